"""How the cost grows with simulated time (1 s … 1 h: linear, constant memory) and with the shaft's
stiffness (1e3 … 1e7 N·m/rad), and the number of clutch switches at every tolerance (the
exhaustive sweep behind test/test_events.py)."""
import time
import tracemalloc

from ..scene import available_scenes, load_scene
from ..solver import advance_layout as AL
from ..solver.simulator import SimulationError, Simulator
from .report import fmt, table

SPANS = (1.0, 10.0, 100.0, 1000.0, 3600.0)
QUICK_SPANS = (1.0, 10.0, 60.0)
STIFFNESSES = (1e3, 1e4, 1e5, 1e6, 1e7)
SWEEP_RTOLS = (1e-4, 1e-5, 1e-6, 1e-7, 1e-8, 1e-9, 1e-10)
VARIANTS = {
    'reduced, exact output': {},
    'reduced, integrated output': {'solver.output_subsystem': 'integrate'},
    'paper, exact output': {'model.formulation': 'paper'},
    'paper, integrated output': {'model.formulation': 'paper',
                                 'solver.output_subsystem': 'integrate'},
}


def time_scaling(cfg, log):
    rows = []
    for span in cfg.scaling_spans:
        sim = Simulator(load_scene('paper'))
        count = [0]

        def consume(block, count=count):
            count[0] += len(block)
        tracemalloc.start()
        t0 = time.perf_counter()
        result = sim.run(span, 0.1, on_samples=consume, keep_samples=False)
        wall = time.perf_counter() - t0
        _, peak = tracemalloc.get_traced_memory()
        tracemalloc.stop()
        rows.append({'span': span, 'wall': wall, 'peak': peak, 'samples': count[0],
                     'switches': result.switch_count + result.graze_count,
                     'rhs': result.diagnostics['rhs_evaluations'],
                     'energy': result.energy['relative_residual']})
        log(f"scaling: {span:g} s simulated in {wall:.2f} s, peak {peak / 1e6:.1f} MB")
    return rows


def stiffness_scaling(cfg, log):
    rows = []
    for c in cfg.scaling_stiffnesses:
        values = dict(load_scene('stiff_shaft'), **{'shaft.stiffness': c})
        sim = Simulator(values)
        row = {'c': c, 'warnings': list(sim.warnings), 'span': cfg.stiffness_span}
        t0 = time.perf_counter()
        try:
            result = sim.run(cfg.stiffness_span, 0.01, keep_samples=False)
        except SimulationError as exc:
            row['status'] = str(exc)[:100]
            rows.append(row)
            continue
        row.update(status='ok', wall=time.perf_counter() - t0, steps=result.steps,
                   rejected=result.rejected, rhs=result.diagnostics['rhs_evaluations'],
                   switches=result.switch_count,
                   substeps=int(sim.counters[AL.C_SUBSTEPS]))
        rows.append(row)
        log(f"scaling: c = {c:g}: {row['wall']:.2f} s for {cfg.stiffness_span:g} s")
    return rows


def event_sweep(cfg, log):
    """Switch counts per scene and solver variant at every rtol; 'same' when all agree."""
    rows = []
    t0 = time.perf_counter()
    for name in available_scenes(n_paths=1):
        for variant, changes in VARIANTS.items():
            counts, late = [], 0
            for rtol in SWEEP_RTOLS:
                sim = Simulator(dict(load_scene(name), **changes,
                                     **{'solver.rtol': rtol, 'solver.atol': rtol * 1e-2}))
                result = sim.run(cfg.sweep_span, 0.01, keep_samples=False)
                counts.append(result.switch_count)
                late += result.diagnostics['possible_missed_events']
            rows.append({'scene': name, 'variant': variant, 'counts': counts, 'late': late})
    log(f"event sweep: {len(rows)} scene/variant pairs × {len(SWEEP_RTOLS)} tolerances, "
        f"{time.perf_counter() - t0:.0f} s")
    return rows


def section_scaling(times, stiffness, cfg):
    L_ = ['## Scaling', '']
    if times:
        L_ += ['**With simulated time** (paper scene, defaults, 0.1 s samples streamed to a '
               'callback and not kept, as `cvt-sim run` can): wall time per simulated second and '
               'the peak of Python/numpy memory (tracemalloc) during the run.', '']
        body = [[f"{r['span']:g}", fmt(r['wall']), f"{r['wall'] / r['span'] * 1e3:.3f}",
                 f"{r['span'] / r['wall']:.0f}", r['samples'], r['switches'],
                 f"{r['peak'] / 1e6:.2f}", fmt(r['energy'])] for r in times]
        L_ += table(['simulated [s]', 'wall [s]', 'wall per simulated s [ms]', 'RTF',
                     'samples', 'clutch events', 'peak memory [MB]', 'energy residual'], body)
        L_ += ['']
    if stiffness:
        L_ += [f"**With shaft stiffness** (stiff_shaft scene, J3 = 1e-4 kg·m², c varied, "
               f"{stiffness[0]['span']:g} s from rest, defaults). The open clutch's ringing "
               "mode √(c·(1/J3 + 1/J4)) is solved in closed form (sub-intervals of ≤ 3 rad, "
               "0.75 rad near contact, watch the slip); the engaged twist mode is integrated, "
               "so its rate sets the steps; the simulator warns when that needs more than 2e6 "
               "steps per simulated second.", '']
        body = []
        for r in stiffness:
            if r['status'] != 'ok':
                body.append([f"{r['c']:g}", r['status'], '', '', '', '', '', ''])
                continue
            body.append([f"{r['c']:g}", fmt(r['wall']), f"{r['wall'] / r['span']:.3g}",
                         r['steps'], r['rejected'], r['rhs'], r['substeps'], r['switches'],
                         'yes' if r['warnings'] else 'no'])
        L_ += table(['c [N·m/rad]', 'wall [s]', 'wall per simulated s [s]', 'steps',
                     'rejected', 'RHS evaluations', 'output sub-intervals', 'switches',
                     'stiffness warning'], body)
        L_ += ['']
    return L_


def section_events(sweep, cfg):
    """Switch counts at every tolerance: a sentence for the scenes that agree everywhere, a row
    per variant for any other."""
    same = sum(len(set(r['counts'])) == 1 for r in sweep)
    L_ = ['## Clutch switches at every tolerance', '']
    L_ += [f"{cfg.sweep_span:g} s per run, rtol {', '.join(f'{r:g}' for r in SWEEP_RTOLS)}, "
           f"atol = 1e-2·rtol: {same} of {len(sweep)} scene/variant pairs switch the same number "
           "of times at every tolerance; 'late' counts switches found only after the step that "
           "crossed them (possibly missed events, reported in the run's diagnostics).", '']
    clean, body = [], []
    for name in dict.fromkeys(r['scene'] for r in sweep):
        mine = [r for r in sweep if r['scene'] == name]
        if all(len(set(r['counts'])) == 1 and r['late'] == 0 for r in mine) and \
                len({r['counts'][0] for r in mine}) == 1:
            clean.append(f"{name} {mine[0]['counts'][0]}")
            continue
        for r in mine:     # a scene with a difference or a late switch: every variant
            body.append([name, r['variant'], ' / '.join(str(c) for c in r['counts']),
                         'same' if len(set(r['counts'])) == 1 else 'DIFFER', r['late']])
    if clean:
        L_ += [f"The same count at every tolerance in all {len(VARIANTS)} variants "
               f"({'; '.join(VARIANTS)}), none late: {', '.join(clean)}.", '']
    if body:
        L_ += table(['scene', 'variant', 'switches at rtol 1e-4 … 1e-10', 'verdict',
                     'late'], body)
        L_ += ['']
    return L_
