"""``cvt-sim replay / analyze / export / recover``: the recording commands, parsed and run.

Each command checks its inputs, calls the library (:mod:`cvt_ros.recording`,
:mod:`cvt_ros.analysis`), turns its results into output and its typed errors into one line on
stderr, and returns the exit code: 0 done, 1 the input was damaged (partial results were
produced), 2 nothing could be done. The library raises and never prints.
"""

from __future__ import annotations

import argparse
import os
import signal
import sys
import threading
from typing import Any

from .arguments import non_negative_float, positive_float

__all__ = ['add_parsers', 'analyze_command', 'export_command', 'recover_command',
           'replay_command']


def _in_range(convert: Any, low: float, high: float, what: str) -> Any:
    """An argparse type: ``convert(text)`` within [low, high], else one argparse error line."""
    def parse(text: str) -> Any:
        try:
            value = convert(text)
        except (ValueError, OverflowError):
            raise argparse.ArgumentTypeError(f'{text[:40]!r} is not {what}') from None
        if not low <= value <= high:
            raise argparse.ArgumentTypeError(f'{text[:40]!r} must be in [{low:g}, {high:g}]')
        return value
    parse.__name__ = what
    return parse


_fraction = _in_range(float, 1e-9, 0.5, 'a number')
_count = _in_range(int, 2, 1_000_000, 'a whole number')


def add_parsers(sub: Any) -> None:
    """Add replay, analyze, export and recover to the ``cvt-sim`` subparsers."""
    replay = sub.add_parser(
        'replay', help='publish a recording on its ROS 2 topics with its timing and /clock',
        description='Publish the messages of an MCAP recording on their topics, with their '
                    'recorded types and QoS (latched topics stay latched), at their recorded '
                    'times scaled by --rate, publishing /clock. For users without rosbag2 '
                    '(`ros2 bag play FILE` does the same).')
    replay.add_argument('file', help='MCAP recording')
    replay.add_argument('--rate', type=positive_float, default=1.0, metavar='R',
                        help='speed factor (2 = twice as fast; default 1)')
    replay.add_argument('--topics', nargs='+', metavar='TOPIC',
                        help='replay only these topics (default: all)')
    replay.add_argument('--loop', action='store_true', help='start over at the end')
    replay.add_argument('--no-clock', action='store_true',
                        help='do not publish /clock (unless it is a recorded topic)')
    replay.add_argument('--delay', type=non_negative_float, default=1.0, metavar='S',
                        help='wait S seconds before the first message, for subscribers to '
                             'connect (default 1)')
    replay.add_argument('--wait-for-subscribers', action='store_true',
                        help='before starting, wait until a subscriber (and every subscriber '
                             'the ROS graph knows of on these topics) is connected')
    replay.set_defaults(func=replay_command)

    analyze = sub.add_parser(
        'analyze', help='crank-cycle metrics (ratio, ripple, twist, clutch torque, efficiency, '
                        'energy) and plots of a recording or CSV',
        description='Read a recording of the node or of `cvt-sim run --mcap` (or a CSV of '
                    '`cvt-sim run --csv` / `cvt-sim export`), split it into crank cycles and '
                    'print, per run, the whole-run figures (start-up included: the peaks) and '
                    'the steady-state figures (steady state detected from the cycle means, or '
                    '"none"), the per-cycle table and the response to each command '
                    '(definitions: docs/recording.md). Outputs are written completely or not '
                    'at all, never onto the input.')
    analyze.add_argument('file', help='MCAP recording or CSV')
    analyze.add_argument('--plots', metavar='DIR',
                         help='write PNG figures into DIR (created if missing)')
    analyze.add_argument('--scene', metavar='SCENE',
                         help='scene (name or .yaml) for the parameters, when the file has none '
                              '(a CSV): needed for the energy residual')
    analyze.add_argument('--namespace', metavar='NS',
                         help='the node namespace to analyse when a recording has several')
    analyze.add_argument('--cycles', default='10', metavar='N|all',
                         help='per-cycle rows to print: the last N (default 10), all, or 0')
    analyze.add_argument('--cycles-csv', metavar='FILE', help='write every cycle\'s metrics')
    analyze.add_argument('--json', metavar='FILE', help='write all results as JSON')
    analyze.add_argument('--steady-tol', type=_fraction, default=5e-3, metavar='X',
                         help='steady state: the cycle means of crank and output speed, ratio, '
                              'motor and output power stay within ±X of their mean (default '
                              '0.005 = ±0.5 %%)')
    analyze.add_argument('--steady-cycles', type=_count, default=10, metavar='N',
                         help='steady state: for at least N crank cycles at the end of the run '
                              '(or of a step\'s window; default 10)')
    analyze.set_defaults(func=analyze_command)

    export = sub.add_parser(
        'export', help='a recording as CSV (samples, and clutch switches and commands)',
        description='Write the joint_states samples of a recording as CSV with the columns of '
                    '`cvt-sim run --csv` plus motor_torque and shaft_torque.')
    export.add_argument('file', help='MCAP recording')
    export.add_argument('--csv', required=True, metavar='OUT', help='sample CSV to write')
    export.add_argument('--events', metavar='OUT',
                        help='also write clutch switches and commands (run, t, topic, value)')
    export.add_argument('--scene', metavar='SCENE',
                        help='scene for the parameters when the recording has none')
    export.add_argument('--namespace', metavar='NS', help='node namespace to export')
    export.set_defaults(func=export_command)

    recover = sub.add_parser(
        'recover', help='turn a crashed (unfinished) or damaged recording into a valid file',
        description='Copy everything readable from a recording that was not finished (the '
                    'process was killed) or is damaged into a new, finished MCAP file with '
                    'summary, statistics and rosbag2 metadata.')
    recover.add_argument('file', help='damaged MCAP recording')
    recover.add_argument('-o', '--output', metavar='OUT',
                         help='recovered file (default: FILE with .recovered.mcap)')
    recover.add_argument('--overwrite', action='store_true', help='replace OUT if it exists')
    recover.set_defaults(func=recover_command)


def _error(command: str, text: str) -> None:
    print(f'cvt-sim {command}: error: {text}', file=sys.stderr)


# ---------------------------------------------------------------------------------- replay
def replay_command(args: Any) -> int:
    """0 = done or stopped by Ctrl-C/SIGTERM, 1 = damaged file (replayed as far as readable),
    2 = cannot replay."""
    import rclpy
    from rclpy.signals import SignalHandlerOptions

    from ..recording.replay import ReplayError, replay

    stop = threading.Event()
    previous = {}

    def handler(signum: int, frame: Any) -> None:
        stop.set()

    for sig in (signal.SIGINT, signal.SIGTERM):
        previous[sig] = signal.signal(sig, handler)
    context = rclpy.Context()
    try:
        rclpy.init(context=context, signal_handler_options=SignalHandlerOptions.NO)
        result = replay(
            args.file, rate=args.rate, topics=args.topics, loop=args.loop,
            clock=not args.no_clock, delay=args.delay,
            wait_for_subscribers=args.wait_for_subscribers, stop=stop,
            log=lambda text: print(text, flush=True), context=context)
    except ReplayError as exc:
        _error('replay', str(exc))
        return 2
    finally:
        rclpy.try_shutdown(context=context)
        for sig, old in previous.items():
            signal.signal(sig, old)
    counts = ', '.join(f'{t} {n}' for t, n in result['per_topic'].items())
    print(f"{'interrupted' if result['interrupted'] else 'done'}: published "
          f"{result['published']} messages ({counts})", flush=True)
    if result['problems']:
        _error('replay', result['problems'][0])
        return 1
    return 0


# ---------------------------------------------------------------------------------- analyze
def _parse_cycles(text: str) -> int | None:
    if text == 'all':
        return None
    value = int(text)
    if value < 0:
        raise ValueError(text)
    return value


def _inputs(args: Any) -> list[str]:
    """The files a command reads: never an output."""
    inputs = [args.file]
    scene = getattr(args, 'scene', None)
    if scene and os.path.exists(scene):
        inputs.append(scene)
    return inputs


def analyze_command(args: Any) -> int:
    """0 = all read, 1 = damaged file (partial results printed), 2 = nothing usable or an
    output cannot be written (then no output file is left)."""
    from ..analysis import AnalysisError, analyze_trace, load
    from ..analysis.report import format_run, to_json, write_cycles_csv
    from ..recording import OutputError, OutputFiles

    outputs = OutputFiles(inputs=_inputs(args))
    try:
        cycles = _parse_cycles(args.cycles)
    except ValueError:
        _error('analyze', f'--cycles expects a number ≥ 0 or "all", got {args.cycles!r}')
        return 2
    try:  # refuse a bad target before the work
        for path in (args.cycles_csv, args.json):
            if path:
                outputs.check(path)
        if args.plots:
            outputs.check(args.plots, directory=True)
    except OutputError as exc:
        _error('analyze', str(exc))
        return 2
    try:
        traces, info = load(args.file, scene=args.scene, namespace=args.namespace)
        analyses, failed = [], []
        for trace in traces:
            try:
                analyses.append(analyze_trace(trace, tolerance=args.steady_tol,
                                              min_cycles=args.steady_cycles))
            except AnalysisError as exc:
                failed.append(f'run {trace.run_index + 1} (t = {trace.t[0]:.6g} … '
                              f'{trace.t[-1]:.6g} s): not analysed: {exc}')
        if failed and (not analyses or not info.problems):
            raise AnalysisError(failed[0])   # (an intact file: one run it cannot analyse)
        # a damaged file: the parts that can be analysed are, the others are named
        info.problems.extend(failed)
    except AnalysisError as exc:
        _error('analyze', str(exc))
        return 2
    head = f'recording        {info.path} ({info.kind}'
    if info.source:
        head += f', {info.source}'
    if info.scene:
        head += f', scene {info.scene}'
    print(head + ')')
    if info.topics:
        print('topics           ' + ', '.join(f'{name} ({count})'
                                              for name, (_, count) in sorted(info.topics.items())))
    if len(analyses) > 1:
        print(f'runs             {len(analyses)} (simulation time went back: ~/reset'
              + ('; or samples lost in a damaged part of the file: see each run\'s notes)'
                 if info.problems else ')'))
    for analysis in analyses:
        print(format_run(analysis, cycles))
    written = []
    try:
        with outputs:
            if args.cycles_csv:
                n = outputs.write(args.cycles_csv, lambda f: write_cycles_csv(f, analyses))
                written.append(f'per-cycle table  {n} rows → {args.cycles_csv}')
            if args.json:
                import json

                data = to_json(analyses, info)
                outputs.write(args.json, lambda f: json.dump(data, f, indent=1,
                                                              allow_nan=False))
                written.append(f'json             → {args.json}')
            if args.plots:
                from ..analysis.plots import plot_all

                files = plot_all(analyses, args.plots, outputs)
                written.append(f'plots            {len(files)} PNG files → {args.plots}')
    except OutputError as exc:
        _error('analyze', f'{exc} (no output file was written)')
        return 2
    for line in written:
        print(line)
    if info.problems:
        first = info.problems[0]
        _error('analyze', (first if first.startswith(args.file) else f'{args.file}: {first}')
               + (f' (+{len(info.problems) - 1} more)' if len(info.problems) > 1 else '')
               + '; the results above cover the readable part')
        return 1
    return 0


# ---------------------------------------------------------------------------------- export
def export_command(args: Any) -> int:
    """0 = exported, 1 = damaged input (the readable part exported), 2 = nothing exported
    (unusable input, or an output that cannot be written: then none is left)."""
    from ..analysis import AnalysisError, load
    from ..analysis.export import export_csv, export_events
    from ..recording import OutputError, OutputFiles

    outputs = OutputFiles(inputs=_inputs(args))
    try:
        outputs.check(args.csv)
        if args.events:
            outputs.check(args.events)
    except OutputError as exc:
        _error('export', str(exc))
        return 2
    try:
        traces, info = load(args.file, scene=args.scene, namespace=args.namespace)
    except AnalysisError as exc:
        _error('export', str(exc))
        return 2
    try:
        with outputs:
            rows = outputs.write(args.csv, lambda f: export_csv(traces, f))
            events = outputs.write(args.events, lambda f: export_events(traces, f)) \
                if args.events else None
    except OutputError as exc:
        _error('export', f'{exc} (no output file was written)')
        return 2
    print(f'samples          {rows} rows → {args.csv}')
    if events is not None:
        print(f'events           {events} rows → {args.events}')
    if info.problems:
        _error('export', f'{args.file}: {info.problems[0]}; the readable part was exported')
        return 1
    return 0


# ---------------------------------------------------------------------------------- recover
def recover_command(args: Any) -> int:
    """0 = recovered, 1 = nothing readable (an empty, finished file was written), 2 = cannot
    recover (not an MCAP file, a bad or unwritable target: then nothing is left there)."""
    from ..recording import RecordingError, recover_file, summary

    out = args.output
    if not out:
        root = args.file[:-5] if args.file.endswith('.mcap') else args.file
        out = root + '.recovered.mcap'
    if not os.path.isfile(args.file):
        _error('recover', f'{args.file}: ' + ('is a directory' if os.path.isdir(args.file)
                                              else 'no such file'))
        return 2
    try:
        result = recover_file(args.file, out, overwrite=args.overwrite)
    except RecordingError as exc:
        _error('recover', str(exc))
        return 2
    for problem in result.problems:
        print(f'skipped/damaged  {problem}')
    if result.skipped:
        print(f'                 {result.skipped} message record(s) did not check out against '
              'their chunk, channel or schema and were left out')
    if result.messages == 0:
        _error('recover', f'{args.file}: no readable message (an empty recording was written '
                          f'to {out})')
        return 1
    info = summary(out)
    span = info.duration_ns * 1e-9
    print(f'recovered        {result.messages} messages ({span:.3f} s) → {out}')
    for name, topic in sorted(info.topics.items()):
        print(f'  {name[:60]:32s} {topic.type_name[:60]:36s} {topic.message_count}')
    return 0
