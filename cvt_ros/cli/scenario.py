"""``cvt-sim scenario ...``: check the inputs, run the library, print, return an exit code.

Exit codes: 0 the run completed, 1 it stopped early (controller error, simulation failure; the
outputs hold everything up to that moment) or it completed but the solver's self-check suspects
a missed clutch event (the outputs are written, the reason is printed, as ``cvt-sim run`` does),
2 bad input (scenario file, controller spec, output path), nothing run.
"""
import sys

from ..recording.errors import RecordingError
from ..scenario.harness import HarnessError, run_scenario
from ..scenario.model import MAX_DURATION, ScenarioError, available_scenarios, load_scenario
from .arguments import positive_seconds


def add_parser(sub):
    """The ``scenario`` command and its subcommands on an argparse subparsers object."""
    scenario = sub.add_parser(
        'scenario', help='run a controller test scenario (set points, loads, metrics)',
        description='Controller tests: a scenario file (config/scenarios/*.yaml; '
                    'docs/controller.md) gives the scene, the set-point and load schedules, '
                    'the crank limits and the sensor/actuator models; a controller runs '
                    'against the device and the step metrics come out as a table, JSON, a PNG '
                    'and an MCAP recording.')
    ssub = scenario.add_subparsers(dest='scenario_command', metavar='SUBCOMMAND')
    run = ssub.add_parser(
        'run', help='run one scenario with a controller',
        description='Run SCENARIO (a file or a shipped scenario name) with a controller. '
                    'Without --controller the reference controller (cycle-mean speed PI) runs. '
                    'Prints the step metrics (rise time, overshoot, settling time 2 %, '
                    'steady-state error, IAE, peak clutch torque, crank travel, switches/s).')
    run.add_argument('scenario', help='scenario file or name (see `cvt-sim scenario list`)')
    who = run.add_mutually_exclusive_group()
    who.add_argument('--controller', metavar='MODULE:FACTORY',
                     help='Python controller: FACTORY(scenario) returns a callable '
                          'controller(measurement) -> crank length [m] or None (default: '
                          'cvt_ros.control.speed_pi:reference_controller)')
    who.add_argument('--controller-cmd', metavar='"COMMAND"',
                     help='an external controller process (e.g. a ROS node) started with this '
                          'shell command; needs --backend dds')
    run.add_argument('--backend', choices=('offline', 'lockstep', 'dds'), default=None,
                     help='offline: against the core; lockstep: the device in this process; '
                          'dds: cvt_node in another process over ROS 2 (default: offline, or '
                          'dds with --controller-cmd)')
    run.add_argument('--realtime', type=float, nargs='?', const=1.0, metavar='FACTOR',
                     help='dds back end: run against the wall clock (HIL rehearsal) at FACTOR x '
                          'real time (default 1) instead of lockstep')
    run.add_argument('--json', metavar='OUT', help='write the metrics as JSON')
    run.add_argument('--mcap', metavar='OUT', help='record the run (rosbag2 MCAP)')
    run.add_argument('--plot', metavar='OUT.png', help='write the plot (speed, crank, load, '
                                                      'clutch)')
    run.add_argument('--duration', type=positive_seconds(MAX_DURATION), metavar='T',
                     help="simulated time [s] instead of the file's: shorter drops the changes "
                          "after T, longer holds the last set point and load")
    run.add_argument('--seed', type=int, help='override the seed')
    run.add_argument('--overwrite', action='store_true', help='replace existing output files')
    run.add_argument('--quiet', action='store_true', help='no progress bar, no table')
    run.set_defaults(func=run_command)
    lst = ssub.add_parser('list', help='list the shipped scenarios',
                          description='The shipped scenarios (config/scenarios), each with the '
                                      'first line of its file; run one by its name.')
    lst.set_defaults(func=list_command)
    scenario.set_defaults(func=lambda args: (scenario.print_help(), 2)[1])


def _fail(message, code=2):
    print(f"cvt-sim scenario: error: {message}", file=sys.stderr)
    return code


def list_command(args):
    from ..scenario.model import resolve_scenario
    for name in available_scenarios():
        first = resolve_scenario(name).read_text().splitlines()[0].lstrip('# ')
        print(f"{name:28s} {first}")
    return 0


PLOT_SUFFIXES = ('.png', '.pdf', '.svg')


def run_command(args):
    overrides = {}
    if args.duration is not None:
        overrides['duration'] = args.duration
    if args.seed is not None:
        overrides['seed'] = args.seed
    backend = args.backend or ('dds' if args.controller_cmd else 'offline')
    if args.controller_cmd and backend != 'dds':
        return _fail(f"--controller-cmd runs an external process: it needs --backend dds, not "
                     f"{backend}")
    if args.realtime is not None and backend != 'dds':
        return _fail('--realtime needs --backend dds (the device against the wall clock)')
    from ..recording import OutputError, OutputFiles
    try:
        scenario = load_scenario(args.scenario, overrides)
        # every target before the run: not an input, not one file twice, a folder that takes
        # it, a format the plot can have, no existing file without --overwrite
        outputs = OutputFiles(inputs=scenario.input_files())
        if args.json:
            outputs.check(args.json, overwrite=args.overwrite)
        if args.plot:
            outputs.check(args.plot, overwrite=args.overwrite, suffixes=PLOT_SUFFIXES)
        if args.mcap:
            outputs.check(args.mcap, overwrite=args.overwrite)
            from ..recording.recorder import check_target
            check_target(args.mcap, args.overwrite)
    except (ScenarioError, RecordingError) as exc:
        return _fail(str(exc))
    options = {}
    if backend == 'dds':
        options = {'controller_cmd': args.controller_cmd, 'realtime': args.realtime}
    bar, progress = (None, None) if args.quiet else _progress(scenario.duration)
    try:   # (the recording is written as the run goes)
        run = run_scenario(scenario, args.controller, backend, progress=progress,
                           mcap=args.mcap, overwrite=args.overwrite, **options)
    except (HarnessError, RecordingError) as exc:
        return _fail(str(exc))
    finally:
        if bar is not None:
            bar.close()
    if not args.quiet:
        print(run.format_table())
    print(run.summary_line())
    code = 0 if run.ok else 1
    missing = run.missing_metrics()
    if missing:   # a run too short for its step metrics is no answer to read as one
        code = _fail(missing, 1)
    suspect = missed_event_text(run.self_check)
    if suspect:   # a wrong answer is never silent (docs/solver.md, the self-check)
        code = _fail(suspect, 1)
    try:
        written = _write_outputs(run, args, outputs)
    except OutputError as exc:
        kept = f"only the recording {args.mcap}, made as the run went" if args.mcap else 'no'
        return _fail(f"{exc} ({kept} output file was written)")
    for line in written:
        print(line)
    if args.mcap:
        print(f"recording → {args.mcap} ({run.recording_count} messages)")
        if run.recording_error is not None:
            code = _fail(f"recording stopped: {run.recording_error}", 1)
    return code


def missed_event_text(check):
    """Why the run's answer is suspect, from the solver's self-check (Simulator.self_check(); None
    where the plant ran in another process: the node's /diagnostics and recording carry it), or
    None when it suspects nothing."""
    if not check or not (check['possible_missed_events'] or check['stray_samples']):
        return None
    parts = []
    if check['possible_missed_events']:
        parts.append(f"{check['possible_missed_events']} clutch switch(es) found only after the "
                     f"step that crossed them (first at t = "
                     f"{check['first_possible_missed_event_s']:.9g} s)")
    if check['stray_samples']:
        parts.append(f"{check['stray_samples']} sample(s) outside their clutch mode (first at "
                     f"t = {check['first_stray_sample_s']:.9g} s)")
    return (f"the solver's self-check suspects a missed clutch event ({check['solver']}): "
            f"{'; '.join(parts)}; a tighter solver.rtol (dopri5) or solver.fixed_step (rk4) in "
            "the scenario's overrides shows whether it is real")


def _write_outputs(run, args, outputs):
    """The JSON and the plot, both or neither (temporary files renamed at the end); the lines
    that say where they went."""
    written = []
    with outputs:
        if args.json:
            import json
            data = run.to_dict()
            outputs.write(args.json, lambda f: (json.dump(data, f, indent=2, allow_nan=False),
                                                f.write('\n')))
            written.append(f"metrics → {args.json}")
        if args.plot:
            import matplotlib

            from ..scenario.plot import plot_run
            fmt = args.plot.rpartition('.')[2].lower()
            with matplotlib.rc_context({'savefig.format': fmt}):   # (a file object: no suffix)
                outputs.write(args.plot, lambda f: plot_run(run, f), 'wb')
            written.append(f"plot → {args.plot}")
    return written


def _progress(duration):
    from tqdm import tqdm
    bar = tqdm(total=duration, unit='s sim', delay=2.0, file=sys.stderr, leave=False,
               bar_format='{l_bar}{bar}| {n:.1f}/{total:.1f} s sim [{elapsed}<{remaining}]')

    def update(done, total):
        bar.update(done - bar.n)
    return bar, update
