"""The compiled core gives the same numbers to the bit whichever process compiled it: kernels
compiled fresh in one process and loaded from numba's disk cache in another (as the node and a
test process, or two sweep workers, do) must agree, or "the device's lockstep run equals the
offline core's to the bit" holds only when both happened to compile alike. With fastmath's
reassociation allowed they differed by 8e-11 after 46 ms (physics/compiled.py); the N-path core
(conveyor_4path) differed by 8e-13 after 1 ms while a caller's call to a non-inlined kernel bound
to whichever copy of the callee the JIT loaded first (physics/compiled.py, _bind_callees_locally).
The process that compiles also checks that every kernel was compiled once (no second version for
a constant argument's value: compile time).

Cost: two subprocesses, the first compiling the one-path and the N-path core (~3 min of CPU on
the 2-core box, the N-path part ~1 min), the second loading them (seconds). The only test that
compiles the core in an empty cache: keep the N-path core's check here rather than in a test of
its own, so the suite pays for it once."""
import os
import subprocess
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent

# the device's one-call period (rk4, as the node runs) and the Simulator's own calls (dopri5),
# over commands and clutch switches
SCRIPT = """
import sys, numpy as np
from cvt_ros.scene import load_scene
from cvt_ros.solver.fidelity import make_simulator
from cvt_ros.solver.period import PeriodStepper
rows = []
sim = make_simulator(load_scene('conveyor', {'solver.method': 'rk4'}))
stepper = PeriodStepper(sim, 1e-3)
for k in range(400):
    if k % 100 == 0:
        sim.command_crank_length(0.04 + 1e-3 * (k // 100))
    rows.append(stepper.advance().copy())
sim = make_simulator(load_scene('conveyor'))
for k in range(400):
    if k % 100 == 0:
        sim.command_crank_length(0.04 + 1e-3 * (k // 100))
    sim.advance(1e-3)
    rows.append(sim.sample())
# the N-path core (paths.count 4): the Simulator's calls and the device's one-call period
paths_rows = []
for stepped in (False, True):
    sim = make_simulator(load_scene('conveyor_4path'))
    stepper = PeriodStepper(sim, 1e-3)
    for k in range(200):
        if k % 100 == 0:
            sim.command_crank_length(0.04 + 1e-3 * (k // 100))
        if stepped:
            paths_rows.append(stepper.advance().copy())
        else:
            sim.advance(1e-3)
            paths_rows.append(sim.sample())
np.savez(sys.argv[1], one=np.array(rows), paths=np.array(paths_rows))
# one compiled version per kernel (physics/compiled.py: no specialization per constant argument)
from numba.core.registry import CPUDispatcher
twice = sorted(f'{m}.{k}: {len(v.signatures)} versions' for m, mod in list(sys.modules.items())
               if m.startswith('cvt_ros.') for k, v in vars(mod).items()
               if isinstance(v, CPUDispatcher) and len(v.signatures) > 1)
assert not twice, twice
"""


def run(cache, out):
    env = dict(os.environ, NUMBA_CACHE_DIR=str(cache))
    proc = subprocess.run([sys.executable, '-c', SCRIPT, str(out)], cwd=ROOT, env=env,
                          capture_output=True, text=True, timeout=1800)
    assert proc.returncode == 0, proc.stderr[-2000:]
    with np.load(out) as saved:
        return saved['one'], saved['paths']


def test_kernels_compiled_fresh_and_loaded_from_the_cache_agree_to_the_bit(tmp_path):
    cache = tmp_path / 'numba_cache'
    fresh, fresh_paths = run(cache, tmp_path / 'fresh.npz')    # compiles, fills the cache
    assert any(cache.rglob('*.nbc'))
    loaded, loaded_paths = run(cache, tmp_path / 'loaded.npz')  # loads them
    assert fresh.shape == (800, loaded.shape[1]) and np.isfinite(fresh[:, :9]).all()
    assert np.array_equal(fresh, loaded), np.nanmax(np.abs(fresh - loaded))
    assert fresh_paths.shape == (400, loaded_paths.shape[1]) and np.isfinite(fresh_paths).all()
    assert np.array_equal(fresh_paths, loaded_paths), np.max(np.abs(fresh_paths - loaded_paths))
