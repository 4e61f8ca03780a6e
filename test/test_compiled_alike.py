"""The compiled core gives the same numbers to the bit whichever process compiled it: kernels
compiled fresh in one process and loaded from numba's disk cache in another (as the node and a
test process, or two sweep workers, do) must agree, or "the device's lockstep run equals the
offline core's to the bit" holds only when both happened to compile alike. With fastmath's
reassociation allowed they differed by 8e-11 after 46 ms (physics/compiled.py). The process that
compiles also checks that every kernel was compiled once (no second version for a constant
argument's value: compile time)."""
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
np.save(sys.argv[1], np.array(rows))
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
    return np.load(out)


def test_kernels_compiled_fresh_and_loaded_from_the_cache_agree_to_the_bit(tmp_path):
    cache = tmp_path / 'numba_cache'
    fresh = run(cache, tmp_path / 'fresh.npy')       # compiles every kernel, fills the cache
    assert any(cache.rglob('*.nbc'))
    loaded = run(cache, tmp_path / 'loaded.npy')     # loads them
    assert fresh.shape == (800, loaded.shape[1]) and np.isfinite(fresh[:, :9]).all()
    assert np.array_equal(fresh, loaded), np.nanmax(np.abs(fresh - loaded))
