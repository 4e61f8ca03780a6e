"""The same clutch events at every tolerance (issue 12): a property of the hybrid solver, not of a
scene. Switch counts are compared across rtol 1e-4 … 1e-10 on every shipped scene and on random
valid machines, for both formulations and both treatments of the open clutch's output; the
output's error falls as the tolerance tightens; the sample grid ends at T; a run that had to
switch a guard found beyond its band says so. The exhaustive sweep (longer spans, every rtol) is
in the benchmark (`cvt-sim bench --sections events`)."""
import math

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from cvt_ros.bench.scaling import VARIANTS
from cvt_ros.physics import layout as L
from cvt_ros.physics.linkage import grashof_bound
from cvt_ros.scene import available_scenes, load_scene
from cvt_ros.solver.output import COL
from cvt_ros.solver.simulator import Simulator
from cvt_ros.solver.witness import hermite_root

RTOLS = (1e-4, 1e-6, 1e-8, 1e-10)
SPAN = 0.5
# A clutch that comes within this (slip relative to the speeds) of a contact it does not make is
# a matter of tolerance: whether it touches is decided by errors of that size, and at rtol 1e-4
# the rocker speed's global error after 0.3 s is ~5e-5 of it (test below)
NEAR_MISS = 1e-3


def switch_count(values, rtol, span=SPAN, sample_dt=0.01):
    sim = Simulator(dict(values, **{'solver.rtol': rtol, 'solver.atol': rtol * 1e-2}))
    result = sim.run(span, sample_dt)
    return len([s for s in result.switches if s.kind != 'graze']), result


def closest_miss(result):
    """The smallest slip (ω3 − ω2, relative to the larger speed) at a minimum inside an open
    stretch of the samples: how near the clutch came to a contact it did not make (the slip
    running down to an engagement has no inner minimum)."""
    s = result.samples
    w2, w3 = s[:, COL['omega2']], s[:, COL['omega3']]
    slip = (w3 - w2) / np.maximum(1.0, np.maximum(abs(w2), abs(w3)))
    open_ = s[:, COL['engaged']] == 0.0
    inner = (open_[1:-1] & open_[:-2] & open_[2:] & (slip[1:-1] <= slip[:-2])
             & (slip[1:-1] <= slip[2:]))
    return float(slip[1:-1][inner].min(initial=np.inf))


@pytest.mark.parametrize('variant', sorted(VARIANTS))
@pytest.mark.parametrize('scene', available_scenes())
def test_every_scene_switches_the_same_at_every_tolerance(scene, variant):
    values = dict(load_scene(scene), **VARIANTS[variant])
    counts = {rtol: switch_count(values, rtol)[0] for rtol in RTOLS}
    assert len(set(counts.values())) == 1, counts


def log_floats(lo, hi):
    return st.floats(math.log(lo), math.log(hi)).map(math.exp)


@st.composite
def machines(draw):
    """Valid machines of the shipped geometry (crank inside the Grashof bound), elastic shaft."""
    return {
        'linkage.crank_length': draw(st.floats(0.005, 0.9 * grashof_bound(0.10, 0.20, 0.20))),
        'inertia.motor': draw(log_floats(0.02, 0.2)),
        'inertia.rocker': draw(log_floats(5e-4, 1e-2)),
        'inertia.clutch_driven': draw(log_floats(1e-4, 1e-2)),
        'inertia.output': draw(log_floats(0.05, 2.0)),
        'shaft.stiffness': draw(log_floats(200.0, 2e4)),
        'shaft.damping': draw(st.one_of(st.just(0.0), log_floats(1e-3, 0.5))),
        'load.torque': draw(st.floats(0.0, 10.0)),
        'initial.crank_speed': draw(st.floats(100.0, 157.0)),
    }


@settings(max_examples=4, deadline=None, print_blob=True,
          suppress_health_check=[HealthCheck.too_slow])
@given(values=machines(), variant=st.sampled_from(sorted(VARIANTS)))
def test_random_machines_switch_the_same_at_every_tolerance(values, variant):
    """Random machines whose clutch never misses a contact by less than NEAR_MISS (the
    reference run at rtol 1e-10, sampled at 20 µs, says): a nearer miss is decided by the
    tolerance itself (test_a_near_miss_is_a_matter_of_tolerance)."""
    values = dict(load_scene('paper'), **values, **VARIANTS[variant])
    reference, result = switch_count(values, 1e-10, 0.3, 2e-5)
    assume(closest_miss(result) > NEAR_MISS)
    counts = {rtol: switch_count(values, rtol, 0.3)[0] for rtol in (1e-4, 1e-7)}
    counts[1e-10] = reference
    assert len(set(counts.values())) == 1, counts


def test_a_near_miss_is_a_matter_of_tolerance():
    """A machine hypothesis found (2026-11-23): at 0.1887 s the open clutch comes within
    1.7e-3 rad/s (3e-5 of the rocker's 54 rad/s) of the rocker without touching it. rtol 1e-5 …
    1e-10 agree (14 switches); at rtol 1e-4 the rocker speed is 3e-3 rad/s off by then and the
    clutch catches — a 0.1 ms engagement more. Not a missed event: an event that errors of the
    chosen size decide, which is why the random-machine property excludes such misses."""
    values = dict(load_scene('paper'), **{
        'linkage.crank_length': 0.03793842151731348, 'inertia.motor': math.exp(-3.0),
        'inertia.rocker': math.exp(-4.9140625), 'inertia.clutch_driven': 0.009842507929860982,
        'inertia.output': math.exp(0.005), 'shaft.stiffness': 258.329139813983,
        'shaft.damping': 0.04083546106285367, 'load.torque': 0.0,
        'initial.crank_speed': 100.0})
    reference, result = switch_count(values, 1e-10, 0.3, 2e-5)
    assert 1e-5 < closest_miss(result) < 1e-4 < NEAR_MISS
    assert [switch_count(values, rtol, 0.3)[0] for rtol in (1e-5, 1e-7)] == [reference] * 2


@pytest.mark.xfail(strict=True, reason=(
    'open defect (issue 12): at rtol 1e-4 this machine switches twice fewer than at 1e-5 … '
    '1e-10 (a short engagement lost), with the PI step control before bb9e5a2 as with the '
    'H211b filter after it. Of 3000 random machines (hypothesis seed 20261127), 3 with the '
    'filter and 4 with PI control switch differently at rtol 1e-4, none at 1e-5 … 1e-10. '
    'Seen in another machine: an open-phase step of 5.5 ms at '
    'rtol 1e-4 over which the slip watch missed the first contact'))
def test_a_random_machine_switches_at_rtol_1e_4_as_at_every_tighter_one():
    values = dict(load_scene('paper'), **{
        'linkage.crank_length': 0.07800527153617962, 'inertia.motor': 0.02,
        'inertia.rocker': 0.0005000000000000001, 'inertia.clutch_driven': 0.00010000000000000009,
        'inertia.output': 0.6765676057669752, 'shaft.stiffness': 199.99999999999991,
        'shaft.damping': 0.0010000000000000002, 'load.torque': 1.101054022132746,
        'initial.crank_speed': 150.0}, **VARIANTS['reduced, exact output'])
    reference, result = switch_count(values, 1e-10, 0.3, 2e-5)
    assert closest_miss(result) > NEAR_MISS   # not a near miss: a contact the reference makes
    assert switch_count(values, 1e-5, 0.3)[0] == reference
    assert switch_count(values, 1e-4, 0.3)[0] == reference


@pytest.mark.parametrize('scene', ['paper', 'stiff_shaft'])
def test_the_output_error_falls_with_the_tolerance(scene):
    values = load_scene(scene)
    phi4 = {}
    for rtol in (1e-4, 1e-6, 1e-8, 1e-12):
        sim = Simulator(dict(values, **{'solver.rtol': rtol, 'solver.atol': rtol * 1e-2}))
        sim.advance(1.0)
        phi4[rtol] = sim.sample()[COL['phi4']]
    errors = [abs(phi4[r] - phi4[1e-12]) / abs(phi4[1e-12]) for r in (1e-4, 1e-6, 1e-8)]
    assert errors[0] > errors[1] > errors[2], errors
    assert errors[2] < 1e-8


def test_twist_release_converges_with_the_tolerance():
    values = dict(load_scene('paper'), **{'clutch.release': 'twist'})
    phi4 = {}
    for rtol in (1e-6, 1e-9, 1e-12):
        sim = Simulator(dict(values, **{'solver.rtol': rtol, 'solver.atol': rtol * 1e-2}))
        sim.advance(2.0)
        phi4[rtol] = sim.sample()[COL['phi4']]
    assert abs(phi4[1e-6] - phi4[1e-12]) / abs(phi4[1e-12]) < 1e-5
    assert abs(phi4[1e-9] - phi4[1e-12]) / abs(phi4[1e-12]) < 1e-8


@pytest.mark.parametrize('duration, dt', [(0.3, 0.1), (1.0, 0.1), (0.7, 0.1), (0.25, 0.05)])
def test_the_sample_grid_ends_exactly_at_the_end_time(duration, dt):
    result = Simulator(load_scene('paper')).run(duration, dt)
    t = result.column('t')
    assert t[-1] == duration
    assert len(t) == round(duration / dt) + 1
    assert np.allclose(np.diff(t), dt)


def test_streamed_samples_equal_kept_samples():
    blocks, located = [], []
    streamed = Simulator(load_scene('paper')).run(2.0, 1e-3, on_samples=blocks.append,
                                                  keep_samples=False, on_switches=located.extend)
    kept = Simulator(load_scene('paper')).run(2.0, 1e-3)
    assert streamed.samples.shape[0] == 0 and len(blocks) > 1
    assert np.array_equal(np.concatenate(blocks), kept.samples)
    # a streamed run keeps no switch objects either (constant memory), but counts them
    assert streamed.switches == [] and located == kept.switches
    switched = [s for s in kept.switches if s.kind != 'graze']
    assert streamed.switch_count == kept.switch_count == len(switched) > 50
    assert streamed.graze_count == kept.graze_count == len(kept.switches) - len(switched)


def test_a_guard_found_beyond_its_band_is_reported_as_a_possible_missed_event():
    sim = Simulator(load_scene('paper'))
    sim.advance(0.02)
    while sim.engaged:
        sim.advance(1e-3)
    # an open clutch whose driven part is put behind the rocker: a catch no step saw coming
    rocker = sim.y[L.OMEGA2]
    sim.y[L.OMEGA3] = rocker - 1.0
    sim.y[L.OMEGA4] = rocker - 1.0
    result = sim.run(1e-4, 1e-5)   # (steps short enough to end before the output catches up)
    assert result.diagnostics['possible_missed_events'] >= 1
    assert any('missed' in w for w in result.diagnostics['warnings'])


@pytest.mark.parametrize('method', ['dopri5', 'rk4'])
def test_a_catch_soon_after_a_release_is_located_not_found_late(method):
    """Conveyor at 40 mm under 16 N·m: the belt's load pulls the output back onto the rocker
    0.6 ms after each release (two engagements a crank turn), inside the first look after the
    release, where the slip starts inside its band. It was found late, by impact (7 in 10 s,
    at every tolerance); now the crossing after the slip left the band upwards is located."""
    values = dict(load_scene('conveyor'), **{'linkage.crank_length': 0.04, 'load.torque': 16.0,
                                              'solver.method': method})
    counts = set()
    for rtol in (RTOLS if method == 'dopri5' else (None,)):
        sim = Simulator(values if rtol is None else dict(values, **{'solver.rtol': rtol}))
        result = sim.run(4.0, 1e-2)
        assert result.diagnostics['possible_missed_events'] == 0, result.diagnostics
        assert not any(s.kind == 'engage_impact' for s in result.switches)
        # each catch placed where the slip is zero to the step's accuracy (a catch at the look's
        # end, 0.18 rad/s below the rocker, would jump the speeds without an impact's books)
        worst = max(abs(s.value) for s in result.switches if s.kind == 'engage')
        assert worst < 1e-2, worst
        counts.add(sim.switch_count)
    assert len(counts) == 1 and counts.pop() > 4.0 * 24 * 3   # > 3 switches a crank turn


def test_a_root_search_starts_at_the_hermite_cubics_root():
    """locate_root's start on the open output's slip: the root of the sub-step's cubic through
    the ends' values and rates, and its slope there; none where the cubic brackets no root."""
    def p(x):
        return (0.3 - x) * (1.0 + x) * (2.0 + x)

    def dp(x):
        return -(1.0 + x) * (2.0 + x) + (0.3 - x) * (3.0 + 2.0 * x)

    g0, d0, g1, d1 = p(0.0), dp(0.0), p(1.0), dp(1.0)
    root, slope = hermite_root(g0, d0, g1, d1, 0.0, 1.0)
    assert root == pytest.approx(0.3, abs=1e-12)
    assert slope == pytest.approx(dp(0.3), rel=1e-9)
    assert hermite_root(g0, d0, g1, d1, 0.1, 0.25) == (-1.0, 0.0)   # both ends above zero
    assert hermite_root(g1, d1, g0, d0, 0.0, 1.0) == (-1.0, 0.0)    # rising: not a fall
