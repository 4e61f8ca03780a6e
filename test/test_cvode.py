"""SUNDIALS CVODE as a peer of the reference (solver/cvode.py): on the paper scene it sees every
clutch switch the project's tight-tolerance reference sees, near the same times, and its φ4 error
falls as rtol is tightened; without scikit-sundae the benchmark leaves it out with a note."""
import numpy as np
import pytest

from cvt_ros.bench import work_precision as wp
from cvt_ros.bench.measure import relative, run_project
from cvt_ros.scene import load_scene
from cvt_ros.solver import cvode

SPAN = 0.5
RTOLS = (1e-4, 1e-7, 1e-10)

needs_cvode = pytest.mark.skipif(cvode.available() is not None,
                                 reason=str(cvode.available()))


@pytest.fixture(scope='module')
def paper():
    values = load_scene('paper')
    return values, run_project(dict(values, **wp.REFERENCE), SPAN)


@needs_cvode
@pytest.mark.parametrize('method', cvode.METHODS)
def test_cvode_sees_the_references_switches_and_converges(paper, method):
    values, ref = paper
    assert len(ref.switches) > 20          # the span has switches to miss
    errors = []
    for rtol in RTOLS:
        r = cvode.solve_cvode(values, SPAN, method=method, rtol=rtol)
        assert r.t == pytest.approx(SPAN, abs=1e-12)
        assert len(r.switch_times) == len(ref.switches), rtol
        dt = np.max(np.abs(np.subtract(r.switch_times, ref.switches)))
        assert dt < 1e3 * rtol, (rtol, dt)   # switches where the reference has them
        assert r.nfev > 0 and r.wall_time > 0.0
        errors.append(relative(float(r.y[6]), ref.phi4))
    assert errors[0] > errors[1] > errors[2], errors
    assert errors[2] < 1e-7, errors


@needs_cvode
def test_modes_alternate_and_method_is_checked(paper):
    values, _ = paper
    r = cvode.solve_cvode(values, 0.1, method='Adams', rtol=1e-6)
    assert all(a != b for a, b in zip(r.switch_modes, r.switch_modes[1:], strict=False))
    with pytest.raises(ValueError, match='Adams'):
        cvode.solve_cvode(values, 0.1, method='RK45')


def test_bench_leaves_cvode_out_with_a_note_when_it_is_missing(monkeypatch):
    monkeypatch.setattr(cvode, 'available', lambda: 'SUNDIALS CVODE not available (test)')

    class Cfg:
        methods = list(wp.METHODS)
        skipped = []

    lines = []
    methods = wp.usable_methods(Cfg, lines.append)
    assert [m.key for m in methods] == [m.key for m in wp.METHODS if not m.cvode]
    assert len(lines) == 1 and 'not available' in lines[0]
    assert wp.section_cvode(None, Cfg)[0].startswith('CVODE left out of this run')
    assert wp.cvode_overhead(Cfg, lines.append) is None
