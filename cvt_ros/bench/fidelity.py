"""Fidelity per scene: speed and error of each model against ``full`` (a BENCHMARKS.md section).

    cvt-sim bench fidelity [--duration 20] [--scenes paper conveyor mixer ...]

For each scene: each fidelity's wall time for the run (minimum of --repeat runs, after the ratio
map is built and cached and the kernels are compiled), its relative error in the mean output
speed and the mean ratio over the last half of the run, and the output speed ripple it shows
(peak-to-peak / mean, at the 10 ms sample rate; the averaged model has none by construction).
"""
import argparse
import sys

from ..scene import load_scene
from ..solver.fidelity import FIDELITIES, fidelity_errors

SCENES = ('paper', 'conveyor', 'mixer', 'stiff_shaft')
SAMPLE_DT = 0.01  # [s]: a long-run output rate; 1 ms sampling would time the sampling instead


def table(scenes, duration, repeat):
    lines = ['| scene | fidelity | wall time [ms] | real-time factor | mean output speed '
             'error | mean ratio error | ripple (full: the reference) |',
             '|---|---|---|---|---|---|---|']
    for name in scenes:
        values = load_scene(name)
        fidelity_errors(values, min(duration, 1.0))  # warm-up: kernels, ratio map
        runs = [fidelity_errors(values, duration, SAMPLE_DT) for _ in range(repeat)]
        for fidelity in FIDELITIES:
            row = runs[0][fidelity]
            wall = min(r[fidelity]['wall_time'] for r in runs)
            lines.append(f"| {name} | {fidelity} | {wall * 1e3:.1f} | {duration / wall:.0f}x | "
                         f"{row['speed_error']:.2e} | {row['ratio_error']:.2e} | "
                         f"{row['ripple']:.2e} |")
        print(f"fidelity: {name} done", file=sys.stderr)
    return '\n'.join(lines)


def main(argv=None):
    parser = argparse.ArgumentParser(prog='cvt-sim bench fidelity',
                                     description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument('--duration', type=float, default=20.0, help='simulated time [s]')
    parser.add_argument('--repeat', type=int, default=3, help='timing repeats (minimum kept)')
    parser.add_argument('--scenes', nargs='+', default=list(SCENES))
    args = parser.parse_args(argv)
    print(table(args.scenes, args.duration, args.repeat))
    return 0


if __name__ == '__main__':
    sys.exit(main())
