"""``cvt-sim``: the command line. Parses, calls a command, exits with its code.

Commands check their inputs and turn the library's typed errors into one clear line on stderr
and exit code 2; the library raises and never prints.
"""
import argparse
import sys

from ..parameters import ParameterError
from ..physics.linkage import GrashofError
from ..recording.errors import RecordingError
from ..scene import SceneError, available_scenes
from ..solver.simulator import SimulationError

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


def _positive_float(text):
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
    if not value > 0.0 or value == float('inf'):
        raise argparse.ArgumentTypeError(f"{text!r} must be a positive finite number")
    return value


def build_parser():
    parser = argparse.ArgumentParser(
        prog='cvt-sim', description=DESCRIPTION,
        epilog=EPILOG.format(scenes=', '.join(available_scenes())),
        formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest='command', metavar='COMMAND')

    run = sub.add_parser(
        'run', help='run a scene as fast as possible, write samples, print a summary',
        description='Run SCENE (a scene name or a ROS 2 parameters file) for --duration seconds '
                    'of simulated time as fast as the core allows. Samples on a uniform grid '
                    '(t = 0 included) go to --csv with the columns t, phi1..phi4, '
                    'omega1..omega4, engaged, twist, clutch_torque, crank_length, load_torque.')
    run.add_argument('scene', help='scene name (see `cvt-sim scenes`) or path to a .yaml file')
    run.add_argument('--duration', type=_positive_float, required=True, metavar='T',
                     help='simulated time [s]')
    run.add_argument('--set', action='append', metavar='KEY=VALUE', default=[],
                     help='override a scene parameter by its dotted name, e.g. '
                          '--set linkage.crank_length=0.04 (repeatable)')
    run.add_argument('--sample-dt', type=_positive_float, default=1e-3, metavar='DT',
                     help='sample interval of the output [s] (default 0.001)')
    run.add_argument('--csv', metavar='FILE', help='write the samples to this CSV file')
    run.add_argument('--quiet', action='store_true', help='no progress bar')
    run.add_argument('--mcap', metavar='FILE',
                     help='record the run to this MCAP file (rosbag2 format: joint_states, '
                          'clutch_engaged at each switch, /clock; see docs/recording.md)')
    run.add_argument('--overwrite', action='store_true', help='replace an existing --mcap file')
    run.add_argument('--fidelity', choices=('full', 'rigid_shaft', 'averaged', 'auto'),
                     help='model fidelity (default: the scene\'s model.fidelity); auto: the '
                          'cheapest whose mean output speed is within --tolerance of full')
    run.add_argument('--tolerance', type=_positive_float, default=0.01, metavar='X',
                     help='relative error budget for --fidelity auto (default 0.01)')
    run.set_defaults(func=_run)

    from .cli_recording import add_parsers
    add_parsers(sub)

    from ..scenario.commands import add_parser as add_scenario_parser
    add_scenario_parser(sub)   # cvt-sim scenario run|list (controller tests)

    scenes = sub.add_parser('scenes', help='list the scenes that ship with the package')
    scenes.set_defaults(func=_scenes)

    params = sub.add_parser('params', help='list every scene parameter (name, unit, default, '
                                           'range, meaning)')
    params.set_defaults(func=_params)

    demo = sub.add_parser('demo', help='the demo: the paper scene offline, then the node '
                                       'driven by a scripted controller')
    demo.set_defaults(func=_demo)

    warm = sub.add_parser('warmup', help='compile the numba kernels into the on-disk cache')
    warm.set_defaults(func=_warmup)

    node = sub.add_parser('node', add_help=False,
                          help='the ROS 2 node (same as cvt_node; --help for its options)')
    node.set_defaults(func=_node)

    bench = sub.add_parser('bench', add_help=False,
                           help='work-precision benchmark → BENCHMARKS.md (--quick for CI size)')
    bench.set_defaults(func=_bench)
    return parser


def _run(args):
    from .run import command
    return command(args)


def _scenes(args):
    from ..scene import resolve
    for name in available_scenes():
        first = resolve(name).read_text().splitlines()[0].lstrip('# ')
        print(f"{name:18s} {first}")
    return 0


def _params(args):
    from ..parameters import SPECS
    for name, spec in SPECS.items():
        print(f"{name:28s} {spec.default!s:>11s} {spec.unit:14s} {spec.range_text():26s} "
              f"{spec.description}")
    return 0


def _demo(args):
    from .demo_node import run_demo
    from .run import format_summary, run_scene, summarize
    print("cvt-sim demo 1/2: the paper's Fig. 2/3 scene offline (i ≈ 0.25), 10 s from "
          "start-up\n")
    _, result = run_scene('paper', 10.0)
    print(format_summary(summarize(result, 10.0), 'paper'))
    print("\ncvt-sim demo 2/2: the ROS 2 node on the conveyor scene, driven by a scripted "
          "controller\n")
    return run_demo()


def _node(args):
    from ..device.main import main as node_main
    return node_main(args.rest)


def _bench(args):
    from ..bench.main import main as bench_main
    return bench_main(args.rest)


def _warmup(args):
    import time

    from ..solver.simulator import Simulator
    t0 = time.perf_counter()
    for method in ('dopri5', 'rk4'):
        sim = Simulator({'solver.method': method})
        sim.run(0.01, 1e-3)
        sim.advance(1e-3)
    print(f"numba kernels compiled and cached in {time.perf_counter() - t0:.1f} s")
    return 0


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
