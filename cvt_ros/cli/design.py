"""``cvt-sim identify | tune | fmu``: design a controller from the device (docs/design.md).

Parse, check the inputs (settings, output paths) before any work, call the library
(:mod:`cvt_ros.design`), print, return an exit code: 0 done, 1 done with a problem (an operating
point of a grid without a model, a tuning whose device check stopped early), 2 bad input and
nothing done, 130 interrupted.
"""
import argparse
import sys

from .arguments import positive_float, positive_seconds
from .run import overrides_from

IDENTIFY_EPILOG = """\
examples:
  cvt-sim identify conveyor --json plant.json --plot plant.png
  cvt-sim identify conveyor --set linkage.crank_length=0.03 --no-sweep
  cvt-sim identify conveyor --grid linkage.crank_length=0.02,0.03,0.04 \\
      --grid load.torque=4:12:3 --no-sweep --out schedule/

The plant is the cycle-mean one (means over whole crank turns: the ripple removed) from the
crank length [m] and the load torque [N·m] to the output speed and the motor speed [rad/s],
linearized at the scene's steady state. docs/design.md explains the models and the JSON.
"""

TUNE_EPILOG = """\
examples:
  cvt-sim tune conveyor                          # SIMC PI, closed-loop time constant = τ
  cvt-sim tune conveyor --tau-c 0.4 --out pi.yaml --plot tune.png

The controller section is ready for a scenario file (config/scenarios/*.yaml: controller:).
"""

FMU_EPILOG = """\
examples:
  cvt-sim fmu conveyor --out conveyor.fmu
  cvt-sim fmu paper --set load.torque=4 --out paper.fmu --step 0.001

A pythonfmu FMU runs Python: the importing machine needs Python 3.11 with cvt_ros and its
dependencies (docs/design.md says exactly what, per importing tool).
"""


def _count(low, high):
    def parse(text):
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text[:40]!r} is not a whole number") from None
        if not low <= value <= high:
            raise argparse.ArgumentTypeError(f"{value} is outside [{low}, {high}]")
        return value
    parse.__name__ = 'count'
    return parse


def _scene_arguments(p):
    p.add_argument('scene', help='scene name (see `cvt-sim scenes`) or path to a .yaml file')
    p.add_argument('--set', action='append', metavar='KEY=VALUE', default=[],
                   help='override a scene parameter, e.g. --set linkage.crank_length=0.03 '
                        '(repeatable): the operating point is the scene\'s crank length and '
                        'load torque')


def _identify_arguments(p, sweep=True):
    g = p.add_argument_group('identification (SI units; defaults from the operating point)')
    g.add_argument('--crank-step', type=positive_float, metavar='M',
                   help='crank-length step [m] (default 2 %% of the crank length)')
    g.add_argument('--load-step', type=positive_float, metavar='NM',
                   help='load-torque step [N·m] (default 5 %% of the load, at least 0.2)')
    if sweep:
        g.add_argument('--no-sweep', action='store_true',
                       help='steps only: no sine sweeps (about half the time)')
        g.add_argument('--max-frequency', type=positive_float, metavar='HZ',
                       help='highest sweep frequency (default 0.2 × the crank frequency; at '
                            'most 0.35 ×: the cycle mean samples once per crank turn)')
        g.add_argument('--min-frequency', type=positive_float, metavar='HZ',
                       help='lowest sweep frequency (default a fifth of the FOPDT corner)')
        g.add_argument('--points', type=_count(2, 200), default=8, metavar='N',
                       help='sweep frequencies, log-spaced (default 8)')
    g.add_argument('--settle-time', type=positive_seconds(3600.0), default=60.0, metavar='S',
                   help='longest run to the steady state [s] (default 60)')
    g.add_argument('--step-time', type=positive_seconds(3600.0), default=30.0, metavar='S',
                   help='longest hold after a step [s] (default 30)')
    g.add_argument('--sample-dt', type=positive_seconds(0.01), default=1e-3, metavar='S',
                   help='sample interval of the experiments [s] (default 0.001)')


def add_parsers(sub):
    """The ``identify``, ``tune`` and ``fmu`` commands on an argparse subparsers object."""
    p = sub.add_parser(
        'identify', help='plant models at an operating point (python-control), gain schedules',
        description='Identify the cycle-mean plant of SCENE at its steady state: small steps of '
                    'the crank length and the load torque (both ways) fitted to FOPDT and '
                    'second-order models, and a frequency response from sine sweeps on the '
                    'full hybrid model. With --grid: the models over a grid of operating '
                    'points, run on the Dask sweep engine (a gain schedule).',
        epilog=IDENTIFY_EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    _scene_arguments(p)
    p.add_argument('--json', metavar='OUT', help='write the models as JSON')
    p.add_argument('--plot', metavar='OUT.png',
                   help='write the figure: step fits and Bode diagrams over the measured points')
    p.add_argument('--overwrite', action='store_true', help='replace existing output files')
    p.add_argument('--quiet', action='store_true', help='no progress lines')
    _identify_arguments(p)
    g = p.add_argument_group('gain schedule (a grid of operating points on Dask)')
    g.add_argument('--grid', action='append', default=[], metavar='NAME=VALUES',
                   help='vary a scene parameter over a grid: NAME=V1,V2,… or NAME=LOW:HIGH:NUM '
                        '(repeatable: the grid is the product)')
    g.add_argument('--out', metavar='DIR',
                   help='grid: output folder (results.parquet, schedule.csv, schedule.png)')
    g.add_argument('--workers', type=_count(1, 1024), metavar='N',
                   help='grid: local worker processes (default: one per core)')
    g.add_argument('--scheduler', metavar='tcp://HOST:8786',
                   help='grid: run on this Dask scheduler instead of a local cluster')
    g.add_argument('--time-budget', type=positive_seconds(1e6), default=3600.0, metavar='S',
                   help='grid: wall time the whole grid may take (default 3600); a grid '
                        'estimated to need more is refused before it runs')
    p.set_defaults(func=identify_command)

    t = sub.add_parser(
        'tune', help='a PI for the reference controller from the identified model',
        description='Identify the crank length → output speed plant of SCENE (FOPDT), tune the '
                    'reference controller (cycle-mean speed PI) by the SIMC rule (Skogestad '
                    '2003) with a closed-loop time constant --tau-c, write the scenario-ready '
                    'controller: section, and check it on the full device with the controller '
                    'kit (offline back end): the predicted closed-loop step against the '
                    "device's.",
        epilog=TUNE_EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    _scene_arguments(t)
    t.add_argument('--tau-c', type=positive_float, metavar='S',
                   help='closed-loop time constant [s] (default: the plant time constant τ; '
                        'at least the dead time θ, SIMC\'s tight tuning)')
    t.add_argument('--setpoint-step', type=float, metavar='RAD_S',
                   help='set-point step of the check [rad/s] (default: 2 %% of the output speed '
                        'or less, so that the P kick stays within a turn of the rate limit)')
    t.add_argument('--duration', type=positive_seconds(3600.0), metavar='S',
                   help='check duration after the step [s] (default 8 τ_c + 4 τ)')
    t.add_argument('--out', metavar='FILE.yaml', help='write the controller: section')
    t.add_argument('--plot', metavar='OUT.png', help='write the predicted-vs-device plot')
    t.add_argument('--json', metavar='OUT', help='write the gains, the model and the check')
    t.add_argument('--overwrite', action='store_true', help='replace existing output files')
    t.add_argument('--quiet', action='store_true', help='no progress lines')
    _identify_arguments(t, sweep=False)
    t.set_defaults(func=tune_command)

    f = sub.add_parser(
        'fmu', help='export the transmission as an FMI 2.0 Co-Simulation FMU (pythonfmu)',
        description='Export SCENE as an FMI 2.0 Co-Simulation FMU built with pythonfmu: inputs '
                    'crank-length command [m] and load torque [N·m]; outputs joint angles and '
                    'speeds, actual crank length, clutch state and torque; the scene\'s '
                    'parameters as FMU parameters. Each doStep advances the same Simulator the '
                    'device runs (Simulator.advance per communication step).',
        epilog=FMU_EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    _scene_arguments(f)
    f.add_argument('--out', required=True, metavar='FILE.fmu', help='the FMU to write')
    f.add_argument('--step', type=positive_seconds(0.1, 1e-6), default=1e-3, metavar='S',
                   help='default communication step of the FMU [s] (default 0.001)')
    f.add_argument('--stop-time', type=positive_seconds(1e6), default=10.0, metavar='S',
                   help="the FMU's default experiment stop time [s] (default 10)")
    f.add_argument('--overwrite', action='store_true', help='replace an existing FMU')
    f.set_defaults(func=fmu_command)


def _fail(command, message, code=2):
    print(f"cvt-sim {command}: error: {message}", file=sys.stderr)
    return code


def _settings(args):
    from ..design.identify import IdentifySettings
    sweep = not getattr(args, 'no_sweep', True)    # (tune: steps only)
    return IdentifySettings(crank_step=args.crank_step, load_step=args.load_step,
                            sample_dt=args.sample_dt, settle_time=args.settle_time,
                            step_time=args.step_time, sweep=sweep,
                            min_frequency=getattr(args, 'min_frequency', None),
                            max_frequency=getattr(args, 'max_frequency', None),
                            points=getattr(args, 'points', 8))


def _say(quiet):
    if quiet:
        return None
    return lambda text: print(f"  … {text}", file=sys.stderr, flush=True)


def identify_command(args):
    from ..design.errors import DesignError
    from ..design.outputs import check_output, write_json
    overrides, origins = overrides_from(args.set)
    try:
        if args.grid:
            return _grid_command(args, overrides, origins)
        if args.out:
            raise DesignError('--out is the folder of a --grid; one operating point writes '
                              '--json and --plot')
        for path, setting in ((args.json, '--json'), (args.plot, '--plot')):
            if path:
                check_output(path, setting, args.overwrite)
        from ..design.identify import identify
        plant = identify(args.scene, overrides, _settings(args), _say(args.quiet), origins)
    except DesignError as exc:
        return _fail('identify', str(exc))
    print(format_plant(plant))
    if args.json:
        write_json(args.json, plant.to_dict())
        print(f"models → {args.json}")
    if args.plot:
        from ..design.plots import plot_plant
        plot_plant(plant, args.plot)
        print(f"plot → {args.plot}")
    return 0


def format_plant(plant):
    """The models as the lines ``cvt-sim identify`` prints: per input and output the better
    model (FOPDT unless the second order fits with less than half its error)."""
    from ..design.frequency import model_error
    from ..design.identify import UNITS
    p = plant.operating_point
    lines = [f"operating point  a = {p.crank_length:.6g} m, load {p.load_torque:.6g} N·m: "
             f"ω̄4 = {p.output_speed:.6g} rad/s, ω̄1 = {p.crank_speed:.6g} rad/s, ratio "
             f"{p.ratio:.5g}, efficiency {p.efficiency:.4g}, crank {p.crank_frequency:.4g} Hz",
             f"{'input → output':29s} {'model':>6s} {'gain':>10s} {'τ [s]':>7s} {'θ [ms]':>7s} "
             f"{'fit':>6s} {'sweep':>6s}  unit"]
    for name, model in plant.inputs.items():
        for output, m in model.outputs.items():
            best = m.model(m.best)
            sweep = ''
            if model.frequency is not None and output == 'output_speed':
                sweep = f"{model_error(model.frequency, best):.2%}"
            kind = 'FOPDT' if m.best == 'fopdt' else '2nd'
            lines.append(f"{name + ' → ' + output:29s} {kind:>6s} "
                         f"{best.gain:10.5g} {best.time_constant:7.4g} {best.delay * 1e3:7.3g} "
                         f"{best.fit_error:6.2%} {sweep:>6s}  {UNITS[name][1]}")
    lines.append("(FOPDT K·e^(-θs)/(τs+1); 2nd: K(τz·s+1)e^(-θs)/(τ²s²+2ζτs+1), τ its slowest "
                 "pole; fit: RMS error / RMS response of the cycle means; sweep: RMS relative "
                 f"error against the sine sweeps; wall time {plant.wall_time:.2f} s)")
    return '\n'.join(lines)


def _grid_command(args, overrides, origins):
    from ..design.errors import DesignError
    from ..design.outputs import check_output
    from ..design.schedule import parse_grid, run_schedule
    if args.json or args.plot:
        raise DesignError('--grid writes its table and figure into --out DIR; --json and '
                          '--plot are for one operating point')
    if not args.out:
        raise DesignError('--grid needs --out DIR (the table and the figure go there)')
    axes = parse_grid(args.grid)
    check_output(args.out, '--out', folder=True)
    from ..sweep.cluster import SweepError
    from ..sweep.table import TableError
    from .sweep import _Progress
    progress = _Progress(args.quiet)    # the sweep command's bar: points done, failed, ETA
    try:
        result = run_schedule(args.scene, axes, args.out, overrides, _settings(args),
                              workers=args.workers, scheduler=args.scheduler,
                              time_budget=args.time_budget, say=_say(args.quiet),
                              origins=origins, on_event=progress)
    except (SweepError, TableError) as exc:
        raise DesignError(str(exc)) from None
    finally:
        progress.close()
    failed = [r for r in result.rows if r['status'] != 'ok']
    print(f"{len(result.rows)} operating points: {len(result.rows) - len(failed)} with a "
          f"model, {len(failed)} without ({result.wall_time:.1f} s)")
    for row in failed[:5]:
        print(f"  point {row['case']}: {row['error'][:300]}")
    print(f"table:  {result.table}\n        {result.csv}\nfigure: {result.figure}")
    return 1 if failed else 0


def tune_command(args):
    from ..design.errors import DesignError
    from ..design.outputs import check_output, write_json
    overrides, origins = overrides_from(args.set)
    try:
        for path, setting in ((args.out, '--out'), (args.plot, '--plot'),
                              (args.json, '--json')):
            if path:
                check_output(path, setting, args.overwrite)
        from ..design.tune import tune
        result = tune(args.scene, overrides, _settings(args), tau_c=args.tau_c,
                      setpoint_step=args.setpoint_step, duration=args.duration,
                      say=_say(args.quiet), origins=origins)
    except DesignError as exc:
        return _fail('tune', str(exc))
    print(result.format())
    if args.out:
        result.write_section(args.out)
        print(f"controller section → {args.out}")
    if args.json:
        write_json(args.json, result.to_dict())
        print(f"tuning → {args.json}")
    if args.plot:
        from ..design.plots import plot_tuning
        plot_tuning(result.check, args.plot)
        print(f"plot → {args.plot}")
    return 0 if result.check.ok else _fail('tune', f"the device check stopped early: "
                                                   f"{result.check.error}", 1)


def fmu_command(args):
    from ..design.errors import DesignError
    from ..design.outputs import check_output
    overrides, origins = overrides_from(args.set)
    try:
        check_output(args.out, '--out', args.overwrite)
        from ..design.fmu import build_fmu
        path, description = build_fmu(args.scene, args.out, overrides, step=args.step,
                                      stop_time=args.stop_time, origins=origins)
    except DesignError as exc:
        return _fail('fmu', str(exc))
    print(description)
    print(f"FMU → {path}")
    return 0
