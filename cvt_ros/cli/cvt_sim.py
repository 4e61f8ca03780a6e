"""``cvt-sim``: the command line. Parses, calls a command, exits with its code.

Each command module of this package adds its parsers and its command functions; a command checks
its inputs, calls the library and turns the library's typed errors into one clear line on stderr.
Exit codes: 0 done, 1 done with a problem (damaged input, suspect answer: a line says which),
2 bad input or nothing could be done, 130 interrupted (Ctrl-C). The library raises, never prints.
"""
import argparse
import sys

from ..parameters import ParameterError
from ..physics.linkage import GrashofError
from ..recording.errors import RecordingError
from ..scene import SceneError, available_scenes
from ..solver.simulator import SimulationError
from . import demo, design, recording, run, scenario, sweep
from .arguments import Parser

DESCRIPTION = """\
Simulate a mechanical pulse continuously variable transmission (motor → crank-rocker linkage →
one-way clutch → torsion shaft → load) as an exact hybrid model: offline as fast as possible, or
as a real-time ROS 2 node. SI units throughout (m, kg·m², N·m, rad, s).
"""

EPILOG = """\
examples:
  cvt-sim run paper --duration 10
  cvt-sim run conveyor --duration 60 --set load.torque=12 --csv conveyor.csv
  cvt-sim run config/scenes/mixer.yaml --duration 5 --set solver.rtol=1e-10
  cvt-sim params                      # every scene parameter with unit, default and range
  cvt-sim run paper --duration 5 --mcap paper.mcap   # record (rosbag2 MCAP)
  cvt-sim analyze paper.mcap --plots plots/          # cycle metrics and figures
  cvt-sim replay paper.mcap --rate 0.5               # back onto ROS topics, with /clock
scenes: {scenes}
"""


PASS_THROUGH = ('node', 'bench')


def build_parser():
    parser = Parser(
        prog='cvt-sim', description=DESCRIPTION,
        epilog=EPILOG.format(scenes=', '.join(available_scenes())),
        formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest='command', metavar='COMMAND')
    run.add_parsers(sub)

    recording.add_parsers(sub)
    scenario.add_parser(sub)   # cvt-sim scenario run|list (controller tests)

    sweep.add_parser(sub)   # cvt-sim sweep CAMPAIGN --out DIR (campaigns on Dask)
    design.add_parsers(sub)   # cvt-sim identify | tune | fmu (design a controller)
    demo.add_parser(sub)

    node = sub.add_parser('node', add_help=False,
                          help='the ROS 2 node (same as cvt_node; --help for its options)')
    node.set_defaults(func=_node)

    bench = sub.add_parser('bench', add_help=False,
                           help='benchmarks → BENCHMARKS.md (--help for what each measures)')
    bench.set_defaults(func=_bench)
    return parser


def _node(args):
    from ..device.main import main as node_main
    return node_main(args.rest)


def _bench(args):
    from ..bench.main import main as bench_main
    return bench_main(args.rest)


def main(argv=None):
    parser = build_parser()
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv and argv[0] in PASS_THROUGH:  # their own parsers (and ROS arguments) take the rest
        args = parser.parse_args(argv[:1])
        args.rest = argv[1:]
    else:
        args = parser.parse_args(argv)
    if not getattr(args, 'func', None):
        parser.print_help()
        return 2
    try:
        return args.func(args)
    except (SceneError, ParameterError, GrashofError, SimulationError, RecordingError) as exc:
        print(f"cvt-sim {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130
    except BrokenPipeError:  # `cvt-sim params | head`
        sys.stderr.close()
        return 0


if __name__ == '__main__':
    sys.exit(main())
