"""Known solver defects: each reproduction re-run so the report says whether it still holds.

Found while writing test/test_stability.py and the benchmarks; the same reproductions are pinned
there (strict xfail while a defect holds, a regression test once it is fixed).
"""
import math
import time

import numpy as np

from ..scene import load_scene
from ..solver.output import COL
from ..solver.simulator import Simulator
from .measure import relative, run_watched

# Found while writing test/test_stability.py and this benchmark; each reproduction is re-run
# here (and pinned as a strict xfail test there) so the report says whether it still holds.
RELEASE_DIP = {  # a release whose clutch-torque dip fits inside one dopri5 step
    'linkage.crank_length': 0.034132, 'inertia.motor': 0.074438, 'inertia.rocker': 0.001787,
    'inertia.clutch_driven': 0.000109, 'inertia.output': 0.231561, 'shaft.stiffness': 979.222055,
    'shaft.damping': 0.013016, 'load.torque': 0.634443, 'motor.model': 'constant_torque',
    'motor.torque': 11.895309, 'initial.crank_speed': 137.305038}


SHORT_CATCH = {  # a short catch near the rocker's peak speed (tiny crank, overrunning load)
    'linkage.crank_length': 0.002648273265094728, 'inertia.motor': 0.020754337873699742,
    'inertia.rocker': 0.006737946999085467, 'inertia.clutch_driven': 0.0, 'inertia.output': 1.0,
    'shaft.stiffness': math.inf, 'load.torque': -0.375, 'initial.crank_speed': 101.0}


MASSLESS_DAMPED = {  # J3 = 0 with shaft damping: θ' = −(c/kd)·θ while open, rate 5e5 1/s
    'linkage.crank_length': 0.001839, 'inertia.motor': 0.037616, 'inertia.rocker': 0.008383,
    'inertia.clutch_driven': 0.0, 'inertia.output': 0.09033, 'shaft.stiffness': 48427.38,
    'shaft.damping': 0.096464, 'load.torque': 9.745568, 'load.viscous': 0.001338,
    'load.quadratic': 0.001085, 'motor.model': 'constant_speed', 'motor.speed': 140.512813}
TIGHT = {'solver.rtol': 1e-10, 'solver.atol': 1e-12}


def clutch_signs(values, span, sample_dt):
    """(real switches, most negative slip while open, most negative torque while closed, φ4)."""
    sim = Simulator(values)
    result = sim.run(span, sample_dt)
    engaged = result.column('engaged') == 1.0
    slip = result.column('omega3') - result.column('omega2')
    torque = result.column('clutch_torque')
    return (len([x for x in result.switches if x.kind != 'graze']),
            float(np.min(slip[~engaged])) if (~engaged).any() else math.nan,
            float(np.min(torque[engaged])) if engaged.any() else math.nan,
            float(sim.sample()[COL['phi4']]))


def default_and_tight(values, span, sample_dt):
    """clutch_signs at the scene's own settings and at rtol 1e-10 (the converged answer)."""
    return (clutch_signs(values, span, sample_dt),
            clutch_signs(dict(values, **TIGHT), span, sample_dt))


def known_defects(log):
    t0 = time.perf_counter()
    paper = load_scene('paper')
    out = []
    # 1. RK4's fixed-step grid under fastmath: a step shorter than half an ulp of t
    # the paper scene is time-invariant: its clock may start at 2047 s
    rows, problem = run_watched(dict(paper, **{'solver.method': 'rk4'}), [2047.5, 2049.0],
                                first_timeout=60.0, min_timeout=10.0, t0=2047.0)
    out.append({
        'title': 'rk4 (the real-time mode) hangs once t ≥ 2048 s',
        'fix': '9ef8be6',
        'test': 'test_stability.py::test_rk4_runs_on_past_2048_s',
        'holds': problem is not None,
        'found': problem or f'ran to {rows[-1]["t"]:g} s',
        'repro': "sim = Simulator(dict(load_scene('paper'), **{'solver.method': 'rk4'})); "
                 "sim.advance(2047.0); sim.advance(0.5); sim.advance(1.0)  # never returns "
                 "(quicker: sim.t = 2047.0 first, the scene being time-invariant)",
        'cause': 'hybrid.advance computes the next grid step as t_start + k·h_fixed − t; under '
                 'fastmath (reassoc, contract) that residual is exact, not a multiple of ulp(t), '
                 'so a step of ~2.0e-13 s passes the `h < 1e-9·h_fixed` test (2e-13 s) while '
                 't + h == t once ulp(t)/2 > 1e-9·h_fixed: t ≥ 2048 s at h = 2e-4 s, ≥ 256 s at '
                 'the stiff shaft\'s refined 1.6e-5 s. The loop never advances (the ROS node '
                 'freezes mid-step). Fix: also bump when t + h <= t, e.g. threshold '
                 'max(1e-9·h_fixed, 4·ulp(t)), or count steps in an integer.'})
    # 2. release dip inside one step
    base = dict(paper, **RELEASE_DIP)
    (n_d, _, tq_d, phi_d), (n_t, _, tq_t, phi_t) = default_and_tight(base, 0.3, 1e-6)
    out.append({
        'title': 'a release whose clutch-torque dip fits inside one step is missed',
        'fix': 'd84ffb0',
        'test': 'test_stability.py::test_a_release_whose_torque_dip_fits_inside_one_step_is_caught',
        'holds': tq_d < -1e-6 * 500.0,
        'found': f'default rtol: {n_d} switches, min clutch torque while closed {tq_d:.3g} N·m, '
                 f'φ4 off by {relative(phi_d, phi_t):.1e} (rel.); rtol 1e-10: {n_t} switches, '
                 f'min {tq_t:.2g} N·m',
        'repro': 'Simulator(dict(load_scene(\'paper\'), **defects.RELEASE_DIP)).run(0.3, 1e-6)',
        'cause': 'the torque release guard has no derivative (clutch_guard returns nan), so '
                 'the step\'s watch (guard_watch.watch_step) skips the Hermite dip test for it; '
                 'a dip that starts and ends '
                 'inside one step goes unseen (also at rtol 1e-8; caught from 1e-9). Fix: '
                 'give the guard its derivative (Tc\' = J3·v\'\' + c·(ω3 − ω4) + kd·(ω3\' − ω4\')) '
                 'or probe the dense output inside the step.'})
    # 3. a short engagement inside one step
    base = dict(paper, **SHORT_CATCH)
    (n_d, s_d, _, phi_d), (n_t, s_t, _, phi_t) = default_and_tight(base, 0.3, 1e-6)
    out.append({
        'title': 'an engagement much shorter than the step is missed at the default rtol',
        'fix': 'd84ffb0',
        'test': 'test_stability.py::test_a_short_engagement_inside_one_step_is_caught_at_the_'
                'default_tolerance',
        'holds': n_d != n_t or s_d < -1e-6,
        'found': f'default rtol: {n_d} switches, min slip while open {s_d:.3g} rad/s, φ4 off by '
                 f'{relative(phi_d, phi_t):.1e} (rel.); rtol 1e-10: {n_t} switches, min slip '
                 f'{s_t:.2g} rad/s',
        'repro': 'Simulator(dict(load_scene(\'paper\'), **defects.SHORT_CATCH)).run(0.3, 1e-6)',
        'cause': 'tiny crank, rigid shaft, a load that lets the output overrun: the rocker\'s '
                 'peak speed exceeds the output\'s for 0.37 ms inside a ~2.6 ms step; the Hermite '
                 'cubic of the slip through the step\'s ends (values and slopes) stays positive, '
                 'so the step\'s watch never probes the dip (caught from rtol 1e-7). Found by the '
                 'property search at the default rtol. Fix: as for the release guard, also probe '
                 'the dense output inside the step (middle, cubic vertex), or bound the step by '
                 'the rocker\'s swing.'})
    # 4. exact open-clutch output misses short re-engagements
    stiff = dict(load_scene('stiff_shaft'), **{'solver.rtol': 1e-12, 'solver.atol': 1e-14,
                                               'solver.max_step': 1e-3})
    n_e, s_e, _, _ = clutch_signs(stiff, 0.3, 2e-6)
    n_i, s_i, _, _ = clutch_signs(dict(stiff, **{'solver.output_subsystem': 'integrate'}),
                                  0.3, 2e-6)
    out.append({
        'title': 'the closed-form open-clutch output misses short re-engagements',
        'fix': 'd84ffb0',
        'test': 'test_stability.py::test_the_exact_output_sees_every_short_reengagement_on_the_'
                'stiff_shaft',
        'holds': n_e != n_i or s_e < -1e-6,
        'found': f'stiff_shaft, 0.3 s, rtol 1e-12: closed form {n_e} switches, min slip '
                 f'{s_e:.3g} rad/s; integrated {n_i} switches, min slip {s_i:.3g} rad/s',
        'repro': "Simulator(dict(load_scene('stiff_shaft'), **{'solver.rtol': 1e-12, "
                 "'solver.atol': 1e-14})).run(0.3, 2e-6)  # vs solver.output_subsystem: "
                 "integrate",
        'cause': '_split_output checks each sub-interval (≤ 0.75 rad of the shaft mode) for a '
                 'dip with a Hermite cubic whose end slopes use the rocker\'s mean acceleration '
                 'over the sub-interval; the rocker\'s curvature there is of the order of the dip '
                 '(independent of rtol). Fix: use v\' at the sub-interval ends (rhs aux '
                 'AUX_ROCKER_ACCEL from the input\'s dense output) or shorter sub-intervals.'})
    # 5. massless damped node
    md = dict(paper, **MASSLESS_DAMPED)
    (n_d, s_d, _, _), (n_t, s_t, _, _) = default_and_tight(md, 0.3, 1e-5)
    out.append({
        'title': 'a massless clutch node with shaft damping is stiff and noisy',
        'fix': 'd84ffb0',
        'test': 'test_stability.py::test_a_massless_damped_node_at_the_default_tolerance',
        'holds': n_d != n_t or s_d < -1e-6,
        'found': f'default rtol: {n_d} switches, min slip {s_d:.3g} rad/s; rtol 1e-10: {n_t} '
                 f'switches, min slip {s_t:.3g} rad/s',
        'repro': "Simulator(dict(load_scene('paper'), **defects.MASSLESS_DAMPED))"
                 ".run(0.3, 1e-5)",
        'cause': 'open, J3 = 0: θ\' = −(c/kd)·θ (rate 5e5 1/s here, up to ~1e8 1/s in the valid '
                 'range) is integrated explicitly at its stability limit, and ω3 = ω4 − c·θ/kd '
                 'multiplies θ\'s error by c/kd: the slip seen by the guard is noise. Seconds of '
                 'wall time per simulated second when c/kd ≳ 1e7. Fix: solve θ in closed form '
                 '(θ0·e^(−c·t/kd)) like the J3 > 0 output.'})
    log(f"known defects: {sum(d['holds'] for d in out)} of {len(out)} reproduce, "
        f"{time.perf_counter() - t0:.1f} s")
    return out


# Fixed defects found by the property searches (test_stability, test_events) after the ones
# re-run above; their reproductions are the tests named. (title, fixing commit(s), test)
FIXED = (
    ('rk4: a located release leaves the step\'s ω3 error as slip', 'b17c382',
     'test_stability.py::test_real_time_mode_refines_a_step_beyond_the_stability_limit '
     '(explicit example)'),
    ('a catch soon after a release is found late, by impact', '9077a9a, 563fd5f',
     'test_events.py::test_a_catch_soon_after_a_release_is_located_not_found_late'),
    ('rk4 near the Grashof bound: the crank\'s energy handed to a heavy output within one step',
     '42ea4fd, 567766e',
     'test_stability.py::test_every_mode_stays_physical_over_valid_parameters (explicit '
     'examples)'),
    ('a dip of the true slip just after the polynomial slip\'s is taken for the interpolant\'s',
     'e9689b8', 'test_events.py::test_a_dip_of_the_true_slip_after_the_polynomial_slips_is_found'),
    ('a clutch torque that falls through zero twice in one step is released at the second fall',
     'e9689b8',
     'test_events.py::test_a_guard_that_falls_twice_in_one_step_switches_at_the_first_fall'),
    ('a short open interval after a release, inside one long look, is found late', 'e9689b8',
     'test_events.py::test_a_short_open_interval_after_a_release_is_seen_in_a_long_look'),
    ('how a run was sampled changed its steps', 'e9689b8',
     'test_events.py::test_how_a_run_is_sampled_does_not_change_it'),
    ('a catch in the first open step after a massless node\'s release is found late', 'fbbb5bc',
     'test_events.py::test_a_catch_in_the_first_step_after_a_massless_nodes_release_is_located'),
    ('a catch that the rocker speed\'s interpolant reaches late is taken past it', '7a10997',
     'test_events.py::test_a_catch_the_rocker_speeds_interpolant_reaches_late_is_located_on_the_'
     'linkage'),
    ('a dip of the true slip inside a look whose polynomial slip ends below zero is taken for '
     'the interpolant\'s', 'b044dd4',
     'test_events.py::test_a_dip_of_the_true_slip_where_the_polynomial_slip_ends_below_zero_is_'
     'found'),
    ('a dip of the clutch torque that the guard\'s polynomial stays above is missed', '8454d54',
     'test_events.py::test_a_dip_of_the_clutch_torque_the_guard_polynomial_stays_above_is_found'),
    ('a release whose re-taken step lands past the guard is placed late', '9fdc842',
     'test_events.py::test_a_release_whose_retaken_step_lands_past_the_guard_is_settled_back'),
    ('a catch before a rise and a second fall in one look is lost', '1ce103c',
     'test_events.py::test_a_catch_before_a_rise_and_a_second_fall_in_one_look_is_found'),
    ('a catch on a massless node that lands past its guard is placed late', 'a81155f',
     'test_events.py::test_a_catch_on_a_massless_node_that_lands_past_its_guard_is_settled_'
     'back'),
    ('a guard that a reset leaves at zero and that falls out of its band without rising first '
     '(the slip after a release on a grazing torque dip; a massless node\'s torque after a '
     'shallow catch) is found late', '158f795',
     'test_events.py::test_a_slip_that_leaves_its_band_downwards_after_a_release_is_caught_there, '
     'test_events.py::test_a_massless_nodes_torque_that_leaves_its_band_downwards_after_a_catch_'
     'is_released_there'),
    ('a twist-rule release whose re-taken step lands past the guard is placed late', '2ccb437',
     'test_events.py::test_a_twist_release_whose_retaken_step_lands_past_the_guard_is_settled_'
     'back'),
)


def section_defects(defects):
    """One line per defect: what it was, the commit that fixed it, the test that pins it. The
    first ones' reproductions are re-run here: one that holds again says so, with its figures;
    how each was found and fixed is in its commit message."""
    L = ['## Known defects', '']
    L += ['Solver defects found by this benchmark and the property searches of test_stability.py '
          'and test_events.py, each pinned by the regression test named (the cause and the fix: '
          'the commit\'s message). Numbers 1–5 are re-run by every `cvt-sim bench` (their '
          'reproductions: cvt_ros/bench/defects.py).', '']
    for i, d in enumerate(defects, 1):
        state = (f"**REPRODUCES**: {d['found']}; reproduction `{d['repro']}`" if d['holds']
                 else f"fixed in {d['fix']} (re-run here: does not reproduce)")
        L += [f"{i}. {d['title']} — {state}; `{d['test']}`."]
    for i, (title, commit, test) in enumerate(FIXED, len(defects) + 1):
        L += [f"{i}. {title} — fixed in {commit}; `{test}`."]
    return L + ['']
