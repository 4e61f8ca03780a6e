"""The commands of ``cvt-sim replay / analyze / export / recover`` (parsed in
tools/cli_recording.py until that moves here).

Each command checks its inputs, calls the library (:mod:`cvt_ros.recording`,
:mod:`cvt_ros.analysis`), turns its results into output and its typed errors into one line on
stderr, and returns the exit code: 0 done, 1 the input was damaged (partial results were
produced), 2 nothing could be done. The library raises and never prints.
"""

from __future__ import annotations

import os
import signal
import sys
import threading
from typing import Any

__all__ = ['analyze_command', 'export_command', 'recover_command', 'replay_command']


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
        analyses = []
        for trace in traces:
            try:
                analyses.append(analyze_trace(trace, tolerance=args.steady_tol,
                                              min_cycles=args.steady_cycles))
            except AnalysisError as exc:
                raise AnalysisError(f'run {trace.run_index + 1}: {exc}') from None
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
        print(f'runs             {len(analyses)} (simulation time went back: ~/reset)')
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
        _error('analyze', f'{args.file}: {info.problems[0]}'
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
