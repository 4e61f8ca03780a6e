"""One harness, several back ends, the same answer: the in-process lockstep device gives the
offline core's trace to the bit, with the reference controller and with sensor/actuator models."""
import numpy as np
import pytest

from cvt_ros.scenario import load_scenario, run_scenario


def same(a, b):
    assert a.ok and b.ok
    assert np.array_equal(a.samples, b.samples)
    assert np.array_equal(a.commands, b.commands, equal_nan=True)
    assert a.switches == b.switches
    assert a.metrics == b.metrics


@pytest.mark.parametrize('name, overrides', [
    ('conveyor_setpoint_steps', {'duration': 4.0}),
    ('conveyor_load_step', {'duration': 6.0, 'seed': 5, 'sensors': {
        'noise': {'position': 1e-3, 'velocity': 0.05}, 'counts_per_turn': 2048,
        'delay': 0.002, 'decimation': 2}, 'actuator': {'deadband': 2e-6, 'backlash': 1e-5}}),
    ('mixer_speed_steps', {'duration': 4.0, 'overrides': {'solver.method': 'rk4'}}),
])
def test_lockstep_in_process_is_bit_identical_to_offline(name, overrides):
    sc = load_scenario(name, overrides)
    offline = run_scenario(sc, backend='offline')
    lockstep = run_scenario(sc, backend='lockstep')
    assert lockstep.backend == 'lockstep'
    same(offline, lockstep)
    if sc.sensors.enabled:
        assert lockstep.clamped == 0 and np.isfinite(lockstep.commands).sum() > 50
