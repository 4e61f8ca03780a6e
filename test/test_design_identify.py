"""Plant identification (``cvt-sim identify``) and PI tuning (``cvt-sim tune``), checked against
what does not come from the identification's own machinery: the static gain of two separate
steady runs, the frequency response of sine sweeps (a second method), scipy's discretization,
a synthetic sinusoid, the SIMC formula, and the full device under the tuned controller.
"""
import math

import numpy as np
import pytest

from cvt_ros.cli import main
from cvt_ros.design.errors import DesignError
from cvt_ros.design.fit import zoh
from cvt_ros.design.frequency import demodulate
from cvt_ros.design.identify import IdentifySettings, identify
from cvt_ros.design.tune import simc
from cvt_ros.scene import load_scene
from cvt_ros.solver.fidelity import make_simulator

# coarse and short: steps, and a 3-point sweep up to a tenth of the crank frequency
QUICK = IdentifySettings(sample_dt=2e-3, fit_dt=4e-3, points=3, max_frequency=2.5)


@pytest.fixture(scope='module')
def plant():
    return identify('conveyor', settings=QUICK)


def _steady_output_speed(crank_length):
    """The cycle-free mean output speed of a plain run at ``crank_length`` (last 3 s of 15)."""
    sim = make_simulator(dict(load_scene('conveyor'), **{'linkage.crank_length': crank_length}))
    sim.run(12.0, 1e-3, keep_samples=False)
    phi4 = sim.sample()[4]
    sim.run(3.0, 1e-3, keep_samples=False)
    return (sim.sample()[4] - phi4) / 3.0


def test_gain_matches_two_separate_steady_runs(plant):
    # the issue's hand identification: ~1.46 rad/s per mm, τ ~0.7 s, −0.45 rad/s per N·m
    model = plant.inputs['crank_length'].outputs['output_speed'].fopdt
    da = 1e-3
    secant = (_steady_output_speed(0.04 + da) - _steady_output_speed(0.04 - da)) / (2 * da)
    assert model.gain == pytest.approx(secant, rel=0.02)
    assert 0.55 < model.time_constant < 0.8 and 0 <= model.delay < 0.05
    assert model.fit_error < 0.02
    load = plant.inputs['load_torque'].outputs['output_speed'].fopdt
    assert load.gain == pytest.approx(-0.45, rel=0.05) and load.fit_error < 0.02


def test_sine_sweeps_agree_with_the_step_models(plant):
    for name in ('crank_length', 'load_torque'):
        model = plant.inputs[name]
        fr = model.frequency
        assert fr.frequency[-1] == pytest.approx(2.5)
        g = model.outputs['output_speed'].fopdt.response(fr.frequency)
        assert np.all(np.abs(fr.output_speed - g) < 0.1 * np.abs(g)), (name, fr.output_speed, g)
        # the phase falls with frequency (a lag), as the model's
        assert np.all(np.diff(np.unwrap(np.angle(fr.output_speed))) < 0)


def test_python_control_objects(plant):
    import control
    g = plant.tf('crank_length')
    assert isinstance(g, control.TransferFunction)
    model = plant.inputs['crank_length'].outputs['output_speed'].fopdt
    assert control.dcgain(g) == pytest.approx(model.gain)
    assert control.dcgain(plant.tf('crank_length', pade_order=2)) == pytest.approx(model.gain)
    ss = plant.state_space()
    assert isinstance(ss, control.StateSpace) and (ss.noutputs, ss.ninputs) == (2, 2)
    dc = control.dcgain(ss)
    for i, output in enumerate(('output_speed', 'motor_speed')):
        for j, name in enumerate(('crank_length', 'load_torque')):
            assert dc[i, j] == pytest.approx(plant.inputs[name].outputs[output].fopdt.gain)


def test_json_holds_the_issue_keys(plant):
    doc = plant.to_dict()
    for name in ('crank_length', 'load_torque'):
        entry = doc[name]
        for key in ('gain', 'time_constant', 'delay', 'num', 'den', 'fit_error',
                    'operating_point', 'second_order', 'motor_speed', 'frequency_response'):
            assert key in entry, (name, key)
        num, den = entry['num'], entry['den']
        assert num[-1] / den[-1] == pytest.approx(entry['gain'])
    assert doc['operating_point']['crank_length'] == pytest.approx(0.04)


def test_zoh_discretization_equals_scipy():
    from scipy.signal import cont2discrete
    for num, den in (([3.0], [0.7, 1.0]), ([-1.7, 1458.0], [0.0173, 0.69, 1.0]),
                     ([2.0, 1.0], [1.0, 0.2, 1.0]), ([1.0], [0.25, 1.0, 1.0]),
                     ([0.3, 1.0], [0.25, 1.0000001, 1.0])):
        b, a = zoh(num, den, 0.004)
        bd, ad, _ = cont2discrete((num, den), 0.004, method='zoh')
        np.testing.assert_allclose(b, np.ravel(bd), rtol=1e-9, atol=1e-10 * np.max(np.abs(bd)))
        np.testing.assert_allclose(a, ad, rtol=1e-12)


def test_demodulation_undoes_the_turn_averaging():
    omega, Y = 2 * math.pi * 3.0, 0.7 - 0.4j
    bounds = np.cumsum(np.r_[0.013, np.full(80, 0.04) + 0.002 * np.sin(np.arange(80))])
    a, b = bounds[:-1], bounds[1:]
    # exact turn means of 5 + 0.1 t + Im(Y e^{jωt})
    means = 5 + 0.05 * (a + b) + (Y.real * (np.cos(omega * a) - np.cos(omega * b))
                                  + Y.imag * (np.sin(omega * b) - np.sin(omega * a))) \
        / (omega * (b - a))
    found, residual = demodulate(bounds, means, omega, 0.0)
    assert abs(found - Y) < 1e-9 and residual < 1e-9


@pytest.mark.parametrize('change, setting', [
    ({'linkage.crank_length': 0.0}, 'linkage.crank_length'),
    ({'motor.breakdown_torque': 1.0}, 'motor.breakdown_torque'),
])
def test_an_operating_point_without_a_steady_state_is_refused(change, setting):
    with pytest.raises(DesignError, match=setting.replace('.', r'\.')):
        identify('conveyor', change, IdentifySettings(sweep=False, sample_dt=2e-3))


@pytest.mark.parametrize('settings, setting', [
    (IdentifySettings(max_frequency=20.0), 'max_frequency'),
    (IdentifySettings(settle_time=0.5), 'settle_time'),
    (IdentifySettings(crank_step=0.05), 'crank_step'),
    (IdentifySettings(sample_dt=0.01), 'sample_dt'),
])
def test_settings_the_cycle_mean_cannot_serve_are_refused(settings, setting):
    with pytest.raises(DesignError, match=setting):
        identify('conveyor', settings=settings)


def test_cli_refuses_an_unwritable_output_before_running(tmp_path, capsys):
    existing = tmp_path / 'plant.json'
    existing.write_text('{}')
    assert main(['identify', 'conveyor', '--json', str(existing)]) == 2
    assert main(['identify', 'conveyor', '--plot', str(tmp_path / 'no' / 'x.png')]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 2 and '--json' in err[0] and 'exists' in err[0] and '--plot' in err[1]
    assert existing.read_text() == '{}'


def test_simc_rule():
    kp, ki, ti = simc(1458.0, 0.665, 0.045, 0.665)
    assert kp == pytest.approx(0.665 / (1458.0 * 0.71)) and ti == 0.665 and ki == kp / ti
    assert simc(1.0, 10.0, 0.1, 0.4)[2] == pytest.approx(2.0)    # τI = 4 (τc + θ)


def test_tune_writes_a_scenario_section_the_device_confirms(tmp_path, capsys):
    section = tmp_path / 'pi.yaml'
    assert main(['tune', 'conveyor', '--quiet', '--sample-dt', '0.002', '--out',
                 str(section)]) == 0
    out = capsys.readouterr().out
    import re
    model, device = map(float, re.search(r'settling \(2 %\) model ([\d.]+) s, device ([\d.]+) s',
                                         out).groups())
    assert device == pytest.approx(model, rel=0.25)
    # the section drops into a scenario file as it is
    from cvt_ros.scenario.model import load_scenario
    scenario = tmp_path / 'tuned.yaml'
    scenario.write_text('scene: conveyor\nduration: 1.0\nsetpoint: {initial: 55.0}\n'
                        + section.read_text())
    gains = load_scenario(scenario).controller_settings
    assert gains['kp'] > 0 and gains['ki'] > 0
