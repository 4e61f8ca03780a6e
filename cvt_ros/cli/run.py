"""``cvt-sim run | scenes | params | warmup``: the offline simulation from the command line.

Parse, call the library (:mod:`cvt_ros.solver.offline`, :mod:`cvt_ros.scene`), print, return an
exit code: 0 done, 1 done but the answer is suspect (a warning says why), 2 bad input.
"""
import contextlib
import math
import sys
import time

from ..parameters import SPECS
from ..physics.linkage import grashof_bound
from ..scene import available_scenes, load_scene, parse_override, resolve
from ..solver.fidelity import choose_fidelity
from ..solver.offline import CsvWriter, SampleStatistics, simulator_for, summarize, tail_start
from ..solver.output import path_columns
from .arguments import positive_float, positive_seconds

# Bounds on what one run may ask for: beyond them it would run for years or fill the disk.
MAX_DURATION = 1e7         # s of simulated time (~4 months)
MAX_SAMPLES = 100_000_000  # rows of output (a CSV of ~20 GB)


def add_parsers(sub):
    run = sub.add_parser(
        'run', help='run a scene as fast as possible, write samples, print a summary',
        description='Run SCENE (a scene name or a ROS 2 parameters file) for --duration seconds '
                    'of simulated time as fast as the core allows. Samples on a uniform grid '
                    '(t = 0 and t = T included) go to --csv with the columns t, phi1..phi4, '
                    'omega1..omega4, engaged, twist, clutch_torque, crank_length, load_torque. '
                    'Exit code 0 done, 1 done but the answer is suspect (a warning says why), '
                    '2 bad input.')
    run.add_argument('scene', help='scene name (see `cvt-sim scenes`) or path to a .yaml file')
    run.add_argument('--duration', type=positive_seconds(MAX_DURATION), required=True,
                     metavar='T', help=f'simulated time [s], at most {MAX_DURATION:g}')
    run.add_argument('--set', action='append', metavar='KEY=VALUE', default=[],
                     help='override a scene parameter by its dotted name, e.g. '
                          '--set linkage.crank_length=0.04 (repeatable; `cvt-sim params`)')
    run.add_argument('--sample-dt', type=positive_seconds(MAX_DURATION), default=1e-3,
                     metavar='DT', help='sample interval of the output [s] (default 0.001)')
    run.add_argument('--csv', metavar='FILE',
                     help='write the samples to this CSV file (replaced if it exists)')
    run.add_argument('--quiet', action='store_true', help='no progress bar')
    run.add_argument('--mcap', metavar='FILE',
                     help='record the run to this MCAP file (rosbag2 format: joint_states, '
                          'clutch_engaged at each switch, /clock; see docs/recording.md)')
    run.add_argument('--overwrite', action='store_true', help='replace an existing --mcap file')
    run.add_argument('--fidelity', choices=('full', 'rigid_shaft', 'averaged', 'auto'),
                     help='model fidelity (default: the scene\'s model.fidelity); auto: the '
                          'cheapest whose mean output speed is within --tolerance of full')
    run.add_argument('--tolerance', type=positive_float, default=0.01, metavar='X',
                     help='relative error budget for --fidelity auto (default 0.01)')
    run.set_defaults(func=run_command)

    scenes = sub.add_parser(
        'scenes', help='list the scenes that ship with the package',
        description='List the shipped scenes (config/scenes/*.yaml, also installed under '
                    'share/cvt_ros) with the first line of each: what it is for. A scene is a '
                    'ROS 2 parameters file; `cvt-sim run NAME` and `cvt_node --ros-args '
                    '--params-file FILE` both read it.')
    scenes.set_defaults(func=scenes_command)

    params = sub.add_parser(
        'params', help='list every parameter (name, value, unit, accepted range, meaning)',
        description='List every parameter of a scene and of the node: dotted name, value, SI '
                    'unit, accepted range and meaning. Without --scene the values are the '
                    'built-in defaults (the paper\'s scene; cvt_node starts from the conveyor '
                    'scene unless given a --params-file). The crank length\'s upper limit is '
                    'the Grashof bound of the scene\'s geometry.')
    params.add_argument('--scene', metavar='SCENE',
                        help='show this scene\'s values and bounds (name or .yaml path)')
    params.add_argument('--node', action='store_true',
                        help='the values cvt_node starts with (base scene: --scene or conveyor; '
                             'solver.method rk4 unless the scene sets it)')
    params.add_argument('--markdown', action='store_true',
                        help='print a Markdown table (docs/node.md\'s is `--node --markdown`)')
    params.set_defaults(func=params_command)

    warm = sub.add_parser(
        'warmup', help='compile the numba kernels into the on-disk cache',
        description='Compile the numerical kernels (numba) once and cache them on disk, so '
                    'that the first run or node start does not pay for it. ./run.sh does this '
                    'at set-up.')
    warm.set_defaults(func=warmup_command)


def overrides_from(set_args):
    """``--set KEY=VALUE`` arguments → (overrides, origins: key → the argument as given)."""
    overrides, origins = {}, {}
    for text in set_args or ():
        key, value = parse_override(text)
        overrides[key] = value
        origins[key] = f"--set {text if len(text) <= 80 else text[:80] + '…'}"
    return overrides, origins


def format_summary(summary, scene, fidelity='full'):
    """The summary as the lines ``cvt-sim run`` prints; ``fidelity``: the model that ran (the
    averaged model follows cycle means: it has no clutch switches and no impact peaks)."""
    s = summary

    def ratio(x):
        return 'undefined' if math.isnan(x) else f"{x:.6f}"
    lines = [
        f"scene            {scene}",
        f"simulated        {s['duration_s']:g} s",
        f"mean ratio i     {ratio(s['mean_ratio'])} (ω4/ω1 over the run), "
        f"{ratio(s['mean_ratio_last_quarter'])} over the last quarter",
        f"mean speeds      crank {s['mean_crank_speed_rad_s']:.4f} rad/s, output "
        f"{s['mean_output_speed_rad_s']:.4f} rad/s (last quarter)",
        f"clutch switches  {s['switches']} ({s['grazing_contacts']} grazing contacts without "
        f"switch)" if fidelity != 'averaged' else
        "clutch switches  n/a: the averaged model has no clutch events (--fidelity full)",
        f"peaks            clutch torque {s['peak_clutch_torque_Nm']:.4f} N·m, twist "
        f"{s['peak_twist_rad']:.6f} rad (whole run)" if fidelity != 'averaged' else
        f"peaks            n/a: the averaged model follows cycle means (its largest clutch "
        f"torque, a cycle mean: {s['peak_clutch_torque_Nm']:.4f} N·m); impacts: --fidelity full",
        *([] if 'switches_per_path' not in s or fidelity == 'averaged' else [
            f"paths            {len(s['switches_per_path'])}: switches "
            f"{', '.join(str(c) for c in s['switches_per_path'])}; peak clutch torque "
            f"{', '.join(f'{x:.4f}' for x in s['peak_clutch_torque_per_path_Nm'])} N·m "
            f"(path 1 … {len(s['switches_per_path'])})"]),
        f"energy balance   residual {s['energy_residual_J']:.3e} J = "
        f"{s['energy_residual_relative']:.2e} of the work done",
        f"solver           {s['steps']} steps, {s['rejected_steps']} rejected"
        + (f" ({s['solver']})" if s.get('solver') else ''),
        f"self-check       {s.get('possible_missed_events', 0)} switches found late, "
        f"{s.get('stray_samples', 0)} samples outside their clutch mode"
        + (" (possibly missed events: see the warnings)"
           if s.get('possible_missed_events') or s.get('stray_samples') else ''),
        f"wall time        {s['wall_time_s']:.4f} s, real-time factor "
        f"{s['real_time_factor']:.0f}x",
    ]
    lines += [f"warning          {text}" for text in s.get('warnings', ())]
    return '\n'.join(lines)


def progress_bar(duration):
    """A tqdm bar on stderr that appears only if the run takes more than 2 s of wall time."""
    from tqdm import tqdm
    bar = tqdm(total=duration, unit='s sim', delay=2.0, file=sys.stderr, leave=False,
               bar_format='{l_bar}{bar}| {n:.1f}/{total:.1f} s sim [{elapsed}<{remaining}]')

    def update(done, total):
        bar.update(done - bar.n)  # update(), not refresh(): keeps the 2 s delay
    return bar, update


def pick_fidelity(args, overrides, origins=None):
    """``--fidelity auto --tolerance X``: probe the fidelities against the full model and keep
    the cheapest within X (relative error of the mean output speed and ratio)."""
    if args.fidelity != 'auto':
        if args.fidelity:
            overrides['model.fidelity'] = args.fidelity
        return
    values = load_scene(args.scene, overrides, origins)
    probe = min(args.duration, 4.0)
    fidelity, table = choose_fidelity(values, args.tolerance, probe=probe)
    print(f"fidelity         auto (tolerance {args.tolerance:g}, probed over {probe:g} s):")
    for name, row in table.items():
        print(f"  {name:12s} output speed error {row['speed_error']:.2e}, ratio error "
              f"{row['ratio_error']:.2e}, wall {row['wall_time']:.3f} s")
    print(f"                 → {fidelity}")
    overrides['model.fidelity'] = fidelity


def run_command(args):
    """Run a scene; returns the exit code."""
    from ..solver.simulator import MAX_KEPT_ROWS
    rows = math.floor(args.duration / args.sample_dt) + 1
    if rows > MAX_SAMPLES or (args.mcap and rows > MAX_KEPT_ROWS):
        limit = MAX_KEPT_ROWS if args.mcap and rows <= MAX_SAMPLES else MAX_SAMPLES
        what = ' recorded (--mcap)' if limit == MAX_KEPT_ROWS else ''
        print(f"cvt-sim run: error: --duration {args.duration:g} / --sample-dt "
              f"{args.sample_dt:g} asks for {rows:.3g} samples{what}, more than {limit:.0e}: "
              f"raise --sample-dt", file=sys.stderr)
        return 2
    overrides, origins = overrides_from(args.set)
    values = load_scene(args.scene, overrides, origins)   # every input error before any work
    columns = path_columns(values['paths.count'])
    pick_fidelity(args, overrides, origins)
    # refuse a target that cannot be written before a long run, not after it
    from ..recording import OutputFiles
    from ..scene import resolve
    targets = OutputFiles(inputs=[str(resolve(args.scene))])
    if args.csv:   # (replaced if it exists, as export's and analyze's outputs are)
        for path in (args.mcap, args.csv):
            if path:
                targets.check(path)
    if args.mcap:
        from ..recording.recorder import check_target
        check_target(args.mcap, args.overwrite)
    statistics = SampleStatistics(tail_start(0.0, args.duration), columns)
    sinks = [statistics.add]
    writing = [0.0]   # wall time spent in the sinks (CSV), not in the simulation

    def on_samples(block):
        t0 = time.perf_counter()
        for sink in sinks:
            sink(block)
        writing[0] += time.perf_counter() - t0
    try:   # the CSV goes to a temporary file renamed at the end: whole, or not at all
        with targets, contextlib.ExitStack() as stack:
            if args.csv:
                csv = stack.enter_context(CsvWriter(targets.temp_path(args.csv), columns))
                sinks.append(csv.add)
            sim = simulator_for(args.scene, overrides, origins)
            update = None
            if not args.quiet:   # after the kernels are loaded: the bar's delay is the run's
                bar, update = progress_bar(args.duration)
                stack.callback(bar.close)
            result = sim.run(args.duration, args.sample_dt, progress=update,
                             on_samples=on_samples, keep_samples=bool(args.mcap))
    except OSError as exc:   # (disk full, quota, I/O error while the CSV streams)
        if not args.csv:
            raise
        raise targets.error(args.csv, exc) from None
    result.wall_time = max(result.wall_time - writing[0], 0.0)   # the simulation's own time
    summary = summarize(result, args.duration, statistics)
    print(format_summary(summary, args.scene, sim.values['model.fidelity']))
    if args.csv:
        print(f"samples          {csv.rows} rows → {args.csv}")
    if args.mcap:
        from ..recording.recorder import write_run
        count, error = write_run(args.mcap, sim, result, scene=args.scene,
                                 overwrite=args.overwrite)
        if error is not None:
            print(f"cvt-sim run: error: {error}", file=sys.stderr)
            return 1
        print(f"recording        {count} messages → {args.mcap}")
    return 1 if summary['warnings'] else 0


def scenes_command(args):
    for name in available_scenes():
        first = resolve(name).read_text().splitlines()[0].lstrip('# ')
        print(f"{name:18s} {first}")
    return 0


def params_command(args):
    if args.node:
        from ..device.descriptors import DEFAULT_SCENE, REALTIME_SOLVER_WHY, node_values
        from ..solver.simulator import fixed_step
        values = node_values(args.scene or DEFAULT_SCENE)
        source = (f"cvt_node's start values (base scene {args.scene or DEFAULT_SCENE}; "
                  "solver.method, unless the scene sets it: rk4 starting in realtime, "
                  "dopri5 in lockstep or fast)")
        if not args.markdown:
            print(f"# {REALTIME_SOLVER_WHY}")
            if values['solver.method'] == 'rk4':
                print(f"# this scene in realtime: "
                      f"{fixed_step(values, values['paths.count'] > 1)[2]}")
    else:
        values = load_scene(args.scene) if args.scene else load_scene(None)
        source = f"scene {resolve(args.scene)}" if args.scene else \
            "built-in defaults (the paper's scene; cvt_node starts from the conveyor scene)"
    if args.markdown:
        from ..device.descriptors import parameter_table
        print(parameter_table(values), end='')
        return 0
    bound = grashof_bound(values['linkage.rocker_length'], values['linkage.coupler_length'],
                          values['linkage.pivot_distance'])
    print(f"# values: {source}")
    print(f"{'name':28s} {'value':>11s} {'unit':14s} {'accepted':26s} meaning")
    for name, spec in SPECS.items():
        accepted = spec.range_text()
        if name == 'linkage.crank_length':
            accepted = f"[0, {bound!r})"
        print(f"{name:28s} {values[name]!s:>11s} {spec.unit:14s} {accepted:26s} "
              f"{spec.description}")
    return 0


def warmup_command(args):
    from ..solver.simulator import Simulator
    t0 = time.perf_counter()
    for method in ('dopri5', 'rk4'):
        sim = Simulator({'solver.method': method})
        sim.run(0.01, 1e-3)
        sim.command_crank_length(0.5 * sim.crank_length_target)   # the actuator's planner
        sim.advance(1e-3)
    print(f"numba kernels compiled and cached in {time.perf_counter() - t0:.1f} s")
    return 0
