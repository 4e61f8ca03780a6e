"""``cvt-sim`` parsers for recordings: replay, analyze, export, recover (added to cli.py's parser).

The commands are in cvt_ros/cli/recording.py: each checks its inputs, calls the library and
returns an exit code: 0 done, 1 the input was damaged (partial results were produced), 2 nothing
could be done. Errors are one line on stderr, never a traceback.
"""

from __future__ import annotations

import argparse
from typing import Any

from ..cli.arguments import non_negative_float, positive_float


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
    replay.set_defaults(func=_replay)

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
    analyze.set_defaults(func=_analyze)

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
    export.set_defaults(func=_export)

    recover = sub.add_parser(
        'recover', help='turn a crashed (unfinished) or damaged recording into a valid file',
        description='Copy everything readable from a recording that was not finished (the '
                    'process was killed) or is damaged into a new, finished MCAP file with '
                    'summary, statistics and rosbag2 metadata.')
    recover.add_argument('file', help='damaged MCAP recording')
    recover.add_argument('-o', '--output', metavar='OUT',
                         help='recovered file (default: FILE with .recovered.mcap)')
    recover.add_argument('--overwrite', action='store_true', help='replace OUT if it exists')
    recover.set_defaults(func=_recover)


def _replay(args: Any) -> int:
    from ..cli.recording import replay_command
    return replay_command(args)


def _analyze(args: Any) -> int:
    import matplotlib
    matplotlib.use('Agg')
    from ..cli.recording import analyze_command
    return analyze_command(args)


def _export(args: Any) -> int:
    from ..cli.recording import export_command
    return export_command(args)


def _recover(args: Any) -> int:
    from ..cli.recording import recover_command
    return recover_command(args)
