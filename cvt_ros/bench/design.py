"""``cvt-sim bench design``: what the design tools cost on this machine.

* ``identify`` at one operating point (the conveyor at its scene values): with the sine sweeps
  (the default) and steps only, the median of ``--rounds`` runs in this process;
* the gain schedule's cost per point: a grid of ``--points`` crank lengths (steps only) on the
  sweep engine's local cluster of 2 workers — wall time of the whole grid / points, and the
  mean of the cases' own wall times (the table's ``wall_time``);
* the FMU's co-simulation overhead per 1 ms communication step: fmpy driving the FMU through its
  FMI 2.0 C API (instantiated once; doStep and one getReal of the outputs per step) against the
  in-process core the device runs (``PeriodStepper.advance``: Simulator.advance + sample in one
  compiled call) and against ``Simulator.advance`` + ``sample`` called from Python — the same
  steps at steady state (after 1 s), the same numbers (checked).
"""
import argparse
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

from .report import environment, publish, table

TITLE = '## Design tools: identify, gain schedule, FMU'


def _identify(rounds, sweep):
    from ..design.identify import IdentifySettings, identify
    times = []
    for _ in range(rounds):
        t0 = time.perf_counter()
        identify('conveyor', settings=IdentifySettings(sweep=sweep))
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def _grid(points, folder):
    from ..design.identify import IdentifySettings
    from ..design.schedule import run_schedule
    values = [round(0.025 + 0.02 * k / max(points - 1, 1), 6) for k in range(points)]
    t0 = time.perf_counter()
    result = run_schedule('conveyor', [('linkage.crank_length', values)], folder, None,
                          IdentifySettings(sweep=False), workers=2, time_budget=1e5)
    wall = time.perf_counter() - t0
    cases = [r['wall_time'] for r in result.rows]
    return wall / points, statistics.mean(cases), sum(r['status'] == 'ok' for r in result.rows)


def _fmu(steps, folder):
    import numpy as np
    from fmpy import extract, read_model_description
    from fmpy.fmi2 import FMU2Slave

    from ..design.fmu import build_fmu
    from ..scene import load_scene
    from ..solver.fidelity import make_simulator
    from ..solver.output import COL
    from ..solver.period import PeriodStepper
    dt, settle = 1e-3, 1000
    path, _ = build_fmu('conveyor', Path(folder) / 'conveyor.fmu', step=dt)
    md = read_model_description(str(path))
    unzipped = extract(str(path))
    refs = [v.valueReference for v in md.modelVariables if v.causality == 'output']
    w4 = next(v.valueReference for v in md.modelVariables if v.name == 'output_shaft.speed')
    fmu = FMU2Slave(guid=md.guid, unzipDirectory=unzipped,
                    modelIdentifier=md.coSimulation.modelIdentifier, instanceName='bench')
    fmu.instantiate()
    fmu.setupExperiment(startTime=0.0)
    fmu.enterInitializationMode()
    fmu.exitInitializationMode()
    t = 0.0
    for _ in range(settle):
        fmu.doStep(t, dt)
        t += dt
    t0 = time.perf_counter()
    for _ in range(steps):
        fmu.doStep(t, dt)
        fmu.getReal(refs)
        t += dt
    fmu_step = (time.perf_counter() - t0) / steps
    fmu_w4 = fmu.getReal([w4])[0]
    fmu.terminate()
    fmu.freeInstance()
    values = load_scene('conveyor')
    sim = make_simulator(values)
    stepper = PeriodStepper(sim, dt)
    for _ in range(settle):
        stepper.advance()
    t0 = time.perf_counter()
    for _ in range(steps):
        row = stepper.advance()
    core_step = (time.perf_counter() - t0) / steps
    same = float(row[COL['omega4']]) == fmu_w4
    sim = make_simulator(values)
    for _ in range(settle):
        sim.advance(dt)
    t0 = time.perf_counter()
    for _ in range(steps):
        sim.advance(dt)
        row = sim.sample()
    python_step = (time.perf_counter() - t0) / steps
    same = same and float(row[COL['omega4']]) == fmu_w4 and np.isfinite(fmu_w4)
    return fmu_step, core_step, python_step, same


def section(cfg, env, figures, command, load):
    ident_sweep, ident_steps, (grid_wall, grid_case, grid_ok), fmu = figures
    fmu_step, core_step, python_step, same = fmu
    lines = [TITLE, '',
             f"`{command}` at {env['revision']} ({env['date']}), {env['cpu']}, {env['cores']} "
             f"cores, Python {env['python']}; load average {env['load'][0]:.2f} at the start, "
             f"{load:.2f} at the end (the machine is shared: ratios from one run).", '']
    lines += table(['what', 'wall time', 'note'], [
        ['`cvt-sim identify conveyor` (steps both ways, both inputs, 8-point sine sweeps)',
         f"{ident_sweep:.2f} s", f"median of {cfg.rounds}, in-process (no CLI start-up)"],
        ['… `--no-sweep` (steps only)', f"{ident_steps:.2f} s", f"median of {cfg.rounds}"],
        [f"gain schedule, {cfg.points} points, steps only, 2 local workers",
         f"{grid_wall:.2f} s per point",
         f"whole grid incl. cluster start / points; the cases' own mean {grid_case:.2f} s; "
         f"{grid_ok}/{cfg.points} ok"],
    ])
    lines += ['', f"FMU co-simulation, conveyor, 1 ms communication steps at steady state "
                  f"({cfg.steps} steps):", '']
    lines += table(['driver', 'per 1 ms step', 'vs in-process core'], [
        ['fmpy → FMU (FMI 2.0 C API → Python slave → Simulator), doStep + getReal(outputs)',
         f"{fmu_step * 1e6:.0f} µs", f"{fmu_step / core_step:.1f}×"],
        ['in-process core (`PeriodStepper.advance`, the device\'s path)',
         f"{core_step * 1e6:.1f} µs", '1×'],
        ['`Simulator.advance` + `sample` from Python', f"{python_step * 1e6:.1f} µs",
         f"{python_step / core_step:.1f}×"],
    ])
    lines += ['', "The FMU's output speed after the run equals the in-process core's bit for bit"
              if same else "WARNING: the FMU's output speed differs from the core's", '']
    return '\n'.join(lines)


def main(argv=None):
    ap = argparse.ArgumentParser(prog='cvt-sim bench design',
                                 description=__doc__.split('\n\n')[0])
    ap.add_argument('--rounds', type=int, default=3, help='identify runs (default %(default)s)')
    ap.add_argument('--points', type=int, default=8, help='grid points (default %(default)s)')
    ap.add_argument('--steps', type=int, default=3000,
                    help='timed FMU steps (default %(default)s)')
    ap.add_argument('--write', '--out', metavar='FILE', dest='out',
                    help="put the section into FILE, e.g. BENCHMARKS.md (default: print it "
                         "only)")
    cfg = ap.parse_args(argv)
    env = environment()

    def log(msg):
        print(f"bench design: {msg}", file=sys.stderr, flush=True)
    log('identify')
    ident_sweep = _identify(cfg.rounds, True)
    ident_steps = _identify(cfg.rounds, False)
    with tempfile.TemporaryDirectory(prefix='cvt_bench_design_') as folder:
        log('grid')
        grid = _grid(cfg.points, Path(folder) / 'grid')
        log('fmu')
        fmu = _fmu(cfg.steps, folder)
    command = './run.sh bench design' + (' ' + ' '.join(argv) if argv else '')
    figures = (ident_sweep, ident_steps, grid, fmu)
    return publish(section(cfg, env, figures, command, os.getloadavg()[0]), cfg.out, TITLE, log)


if __name__ == '__main__':
    sys.exit(main())
