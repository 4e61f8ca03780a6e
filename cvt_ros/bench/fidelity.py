"""Fidelity per scene: speed and error of each model against ``full`` (a BENCHMARKS.md section).

    cvt-sim bench fidelity [--duration 20] [--scenes paper conveyor mixer ...] [--write FILE]

For each scene: each fidelity's wall time for the run (minimum of --repeat runs, after the ratio
map is built and cached and the kernels are compiled), its relative error in the mean output
speed and the mean ratio over the last half of the run, and the output speed ripple it shows
(peak-to-peak / mean, at the 10 ms sample rate; the averaged model has none by construction).
"""
import argparse
import os
import sys

from ..scene import load_scene
from ..solver.fidelity import FIDELITIES, fidelity_errors
from .report import environment, publish, stamp

TITLE = '## Fidelity per scene'

SCENES = ('paper', 'conveyor', 'mixer', 'stiff_shaft')
SAMPLE_DT = 0.01  # [s]: a long-run output rate; 1 ms sampling would time the sampling instead


def table(scenes, duration, repeat):
    """One row per scene; each cell lists the fidelities in FIDELITIES' order."""
    others = [f for f in FIDELITIES if f != 'full']
    lines = [f"| scene | real-time factor ({' / '.join(FIDELITIES)}) | mean output speed error "
             f"({' / '.join(others)}) | mean ratio error ({' / '.join(others)}) | ripple "
             f"({' / '.join(FIDELITIES)}) |", '|---|---|---|---|---|']
    for name in scenes:
        values = load_scene(name)
        fidelity_errors(values, min(duration, 1.0))  # warm-up: kernels, ratio map
        runs = [fidelity_errors(values, duration, SAMPLE_DT) for _ in range(repeat)]
        rtf = [f"{duration / min(r[f]['wall_time'] for r in runs):.0f}×" for f in FIDELITIES]
        speed = [f"{runs[0][f]['speed_error']:.2e}" for f in others]
        ratio = [f"{runs[0][f]['ratio_error']:.2e}" for f in others]
        ripple = [f"{runs[0][f]['ripple']:.2e}" for f in FIDELITIES]
        lines.append(f"| {name} | {' / '.join(rtf)} | {' / '.join(speed)} | {' / '.join(ratio)} "
                     f"| {' / '.join(ripple)} |")
        print(f"fidelity: {name} done", file=sys.stderr)
    return '\n'.join(lines)


def main(argv=None):
    parser = argparse.ArgumentParser(prog='cvt-sim bench fidelity',
                                     description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument('--duration', type=float, default=20.0, help='simulated time [s]')
    parser.add_argument('--repeat', type=int, default=3, help='timing repeats (minimum kept)')
    parser.add_argument('--scenes', nargs='+', default=list(SCENES))
    parser.add_argument('--write', metavar='FILE',
                        help=f'put the section "{TITLE[3:]}" into FILE (e.g. BENCHMARKS.md)')
    args = parser.parse_args(argv)
    env, load0 = environment(), os.getloadavg()[0]
    rows = table(args.scenes, args.duration, args.repeat)
    command = ' '.join(['cvt-sim bench fidelity'] + list(sys.argv[1:] if argv is None else argv))
    text = '\n'.join([
        TITLE, '', stamp(command, env, (load0, os.getloadavg()[0])), '',
        f'Each scene {args.duration:g} s from rest at every fidelity, {SAMPLE_DT * 1e3:g} ms '
        f'samples, the minimum of {args.repeat} runs after a warm-up that also builds and caches '
        'the averaged model\'s ratio map; errors of the mean output speed and mean ratio over '
        'the last half against `full`; ripple = peak-to-peak / mean of ω4. `cvt-sim run '
        '--fidelity auto --tolerance X` makes this comparison over a short probe and runs the '
        'cheapest fidelity within X.', '', rows, ''])
    return publish(text, args.write, TITLE, lambda msg: print(f'fidelity: {msg}', file=sys.stderr))


if __name__ == '__main__':
    sys.exit(main())
