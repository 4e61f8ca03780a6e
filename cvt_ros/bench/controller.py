"""Controller kit: a scenario with the reference controller on each back end (BENCHMARKS.md).

    python -m cvt_ros.bench.controller [--scenario conveyor_shift_60s] [--repeat 3]
                                       [--backends offline lockstep dds]

For each back end: the wall time of the run (from the t = 0 sample to the end; a dds node's
start-up is not in it; minimum of --repeat runs after a warm-up), the real-time factor, the time
per control period, and the difference of its trace from the offline one (max |Δ| over the
joint positions, speeds, torques and the crank length: 0 means bit-identical) and of its
metrics. The machine's load average is printed before and after.
"""
import argparse
import os
import platform
import sys

import numpy as np

from ..scenario import load_scenario, run_scenario
from ..solver.output import COL

COMPARED = ('phi1', 'phi2', 'phi3', 'phi4', 'omega1', 'omega2', 'omega3', 'omega4',
            'clutch_torque', 'crank_length', 'load_torque', 'motor_torque', 'shaft_torque')


def trace_difference(run, reference):
    n = min(len(run.samples), len(reference.samples))
    cols = [COL[c] for c in COMPARED]
    return float(np.max(np.abs(run.samples[:n, cols] - reference.samples[:n, cols])))


def measure(scenario, backends, repeat):
    results = {}
    for backend in backends:
        runs = []
        for i in range(repeat + (backend != 'dds')):   # a warm-up run in process
            run = run_scenario(scenario, backend=backend)
            if not run.ok:
                raise RuntimeError(f"{backend}: {run.error}")
            if i or backend == 'dds':
                runs.append(run)
        results[backend] = min(runs, key=lambda r: r.wall_time)
        print(f"controller bench: {backend} {results[backend].real_time_factor:.1f}x",
              file=sys.stderr)
    return results


def table(scenario, results):
    ref = results.get('offline')
    lines = ['| back end | wall time [s] | real-time factor | µs per control period | '
             'max \\|Δ\\| of the trace vs offline | same metrics as offline |',
             '|---|---|---|---|---|---|']
    for backend, run in results.items():
        diff = trace_difference(run, ref) if ref is not None else float('nan')
        same = ref is not None and all(
            a == b or (a != a and b != b) for a, b in zip(run.metrics.values(),
                                                          ref.metrics.values(), strict=True))
        lines.append(f"| {backend} | {run.wall_time:.3f} | {run.real_time_factor:.1f}x | "
                     f"{run.wall_time / scenario.periods * 1e6:.1f} | {diff:.3g} | "
                     f"{'yes' if same else 'no'} |")
    return '\n'.join(lines)


def main(argv=None):
    parser = argparse.ArgumentParser(prog='python -m cvt_ros.bench.controller',
                                     description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument('--scenario', default='conveyor_shift_60s')
    parser.add_argument('--backends', nargs='+', default=['offline', 'lockstep', 'dds'])
    parser.add_argument('--repeat', type=int, default=3)
    args = parser.parse_args(argv)
    scenario = load_scenario(args.scenario)
    load0 = os.getloadavg()
    results = measure(scenario, args.backends, args.repeat)
    load1 = os.getloadavg()
    print(f"Scenario {scenario.name} ({scenario.duration:g} s, control period "
          f"{scenario.control_period * 1e3:g} ms, reference controller, "
          f"solver {scenario.values['solver.method']}). Machine: {os.cpu_count()} CPUs, "
          f"Python {platform.python_version()}, load average {load0[0]:.2f} before, "
          f"{load1[0]:.2f} after.\n")
    print(table(scenario, results))
    return 0


if __name__ == '__main__':
    sys.exit(main())
