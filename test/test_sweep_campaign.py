"""Campaign files and their cases, without a cluster: the shipped campaigns load, a bad file is
one clear error before any case runs, expansion is deterministic and case ids are stable."""
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

from cvt_ros.sweep import CampaignError, build_tasks, expand, load_campaign

ROOT = Path(__file__).resolve().parent.parent
CAMPAIGNS = ROOT / 'config' / 'campaigns'


def write(tmp_path, text, name='c.yaml'):
    path = tmp_path / name
    path.write_text(textwrap.dedent(text))
    return path


def error_of(tmp_path, text):
    with pytest.raises(CampaignError) as info:
        build_tasks(load_campaign(write(tmp_path, text)))
    return str(info.value)


@pytest.mark.parametrize('name,cases,kind', [('conveyor_ratio_map', 45, 'scene'),
                                             ('conveyor_shaft_stiffness', 30, 'scene'),
                                             ('conveyor_pi_gains', 16, 'scenario')])
def test_shipped_campaigns_load_and_expand(name, cases, kind):
    campaign = load_campaign(CAMPAIGNS / f'{name}.yaml')
    tasks = build_tasks(campaign)
    assert campaign.kind == kind and campaign.case_count() == len(tasks) == cases
    assert [t.index for t in tasks] == list(range(cases))
    assert len({t.case_id for t in tasks}) == cases
    for m in ('peak_clutch_torque', 'switches_per_second', 'energy_residual'):
        assert m in campaign.metrics
    assert set(campaign.summary) == {'x', 'y', 'metrics'}


def test_grid_order_last_axis_fastest_and_values_rounded():
    campaign = load_campaign(CAMPAIGNS / 'conveyor_ratio_map.yaml')
    cases = expand(campaign)
    assert cases[0] == {'linkage.crank_length': 0.01, 'load.torque': 0.0}
    assert cases[1] == {'linkage.crank_length': 0.01, 'load.torque': 4.0}
    assert [c['linkage.crank_length'] for c in cases[::5]] == [
        0.01, 0.02, 0.03, 0.04, 0.05, 0.06, 0.07, 0.08, 0.09]   # not 0.060000000000000005


def test_case_ids_are_stable_and_follow_the_inputs(tmp_path):
    base = """\
        scene: conveyor
        duration: 2.0
        vary:
          load.torque: [1.0, 2.0]
        """
    ids = [t.case_id for t in build_tasks(load_campaign(write(tmp_path, base)))]
    assert ids == [t.case_id for t in build_tasks(load_campaign(write(tmp_path, base, 'd.yaml')))]
    grown = base.replace('[1.0, 2.0]', '[1.0, 2.0, 3.0]')
    assert [t.case_id for t in build_tasks(load_campaign(write(tmp_path, grown)))][:2] == ids
    other = base + 'overrides: {shaft.damping: 0.1}\n'
    assert not set(ids) & {t.case_id for t in build_tasks(load_campaign(write(tmp_path, other)))}
    longer = base.replace('duration: 2.0', 'duration: 3.0')
    assert not set(ids) & {t.case_id for t in build_tasks(load_campaign(write(tmp_path, longer)))}


@pytest.mark.parametrize('sampling', ['random', 'latin_hypercube'])
def test_random_and_latin_hypercube_are_seeded(tmp_path, sampling):
    text = f"""\
        scene: conveyor
        duration: 1.0
        sampling: {sampling}
        samples: 20
        seed: 7
        vary:
          linkage.crank_length: {{range: [0.02, 0.08]}}
          shaft.stiffness: {{range: [200, 1.0e5], scale: log}}
          solver.method: [dopri5, rk4]
        """
    first = expand(load_campaign(write(tmp_path, text)))
    assert first == expand(load_campaign(write(tmp_path, text, 'again.yaml')))
    assert first != expand(load_campaign(write(tmp_path, text.replace('seed: 7', 'seed: 8'))))
    a = np.array([c['linkage.crank_length'] for c in first])
    c = np.array([c['shaft.stiffness'] for c in first])
    assert a.min() >= 0.02 and a.max() <= 0.08 and c.min() >= 200 and c.max() <= 1e5
    assert {x['solver.method'] for x in first} == {'dopri5', 'rk4'}
    if sampling == 'latin_hypercube':   # one sample in each of the 20 strata of every axis
        assert sorted(np.floor((a - 0.02) / 0.06 * 20).astype(int)) == list(range(20))
        strata = np.floor(np.log(c / 200) / np.log(1e5 / 200) * 20).astype(int)
        assert sorted(strata) == list(range(20))


@pytest.mark.parametrize('body,expected', [
    ("scene: conveyor\nduration: 1\nvary: {load.torque: [1]}\nmetric: [x]\n",
     "unknown key 'metric' (did you mean metrics?)"),
    ("scene: conveyor\nduration: 1\nvary: {load.torqe: [1]}\n",
     "'load.torqe': unknown parameter; did you mean load.torque?"),
    ("scene: conveyor\nduration: 1\nvary: {time_mode: [fast]}\n", "time_mode: a node parameter"),
    ("scene: conveyor\nduration: 1\nvary: {load.torque: {range: [5, 5], num: 3}}\n",
     "range: [5, 5] is empty"),
    ("scene: conveyor\nduration: 1\nvary: {load.torque: {range: [8, 2], num: 3}}\n",
     "range: [8, 2] is empty"),
    ("scene: conveyor\nduration: 1\nvary: {load.torque: []}\n", "values: empty list"),
    ("scene: conveyor\nduration: 1\nvary: {load.torque: {range: [0, .inf], num: 3}}\n",
     "range[1]: inf is not a finite number"),
    ("scene: conveyor\nduration: 1\nvary: {load.torque: [1.0, .nan]}\n",
     "load.torque: nan is not a finite number"),
    ("scene: conveyor\nduration: .inf\nvary: {load.torque: [1]}\n",
     "duration: inf is not a finite number"),
    ("scene: conveyor\nduration: 1\nvary: {inertia.output: [1.0e9]}\n",
     "inertia.output: 1e+09 kg*m^2 is outside [1e-06, 10000]"),
    ("scene: conveyor\nduration: 1\nvary: {shaft.stiffness: {range: [0, 10], num: 2, "
     "scale: log}}\n", "shaft.stiffness: 0 N*m/rad is outside"),
    ("scene: conveyor\nduration: 1\nsampling: random\nsamples: 4\n"
     "vary: {load.torque: {range: [0, 1], num: 3}}\n", "num: random sampling draws"),
    ("scene: conveyor\nduration: 1\nvary: {load.torque: {range: [0, 1]}}\n", "num: missing"),
    ("scene: conveyor\nduration: 1\nvary: {controller.kp: [1.0e-3]}\n",
     "controller settings vary the reference controller of a scenario campaign"),
    ("scene: conveyor\nduration: 1\nvary: {load.torque: [1]}\nmetrics: [overshoot]\n",
     "'overshoot': a metric of scenario campaigns"),
    ("scene: conveyor\nscenario: conveyor_load_step\nvary: {load.torque: [1]}\n",
     "name either scene:"),
    ("scene: conveyor\nduration: 1\nvary: {load.torque: [1]}\ncases: [{load.torque: 1}]\n",
     "not both"),
    ("scene: conveyor\nduration: 1\ncases: [{load.torque: 1}, {load.torque: 1}]\n",
     "cases[1]: the same case as cases[0]"),
    ("scene: conveyor\nduration: 1\nvary: {linkage.crank_length: [0.05, 0.09]}\n"
     "overrides: {linkage.rocker_length: 0.08}\n",
     "case 1 (linkage.crank_length = 0.09): linkage.crank_length"),
    ("scenario: conveyor_setpoint_steps\nvary: {controller.kp: [-1.0e-3]}\n",
     "controller.kp: -0.001 must be ≥ 0"),
    ("scenario: conveyor_setpoint_steps\nvary: {controller.crank_min: [0.01, 0.2]}\n",
     "case 1 (controller.crank_min = 0.2): controller.crank_max: 0.09 m must be above"),
    ("scene: nowhere\nduration: 1\nvary: {load.torque: [1]}\n", "scene: scene 'nowhere' not "
                                                               "found"),
    # was: every case ran, then failed in the analysis ('the crank turns more than once')
    ("scene: conveyor\nduration: 1\nsample_dt: 0.05\nvary: {load.torque: [1, 2]}\n",
     "case 0 (load.torque = 1.0): sample_dt: 0.05 s gives fewer than 4 samples per crank turn"),
])
def test_bad_campaigns_are_one_clear_error(tmp_path, body, expected):
    text = error_of(tmp_path, body)
    assert str(tmp_path / 'c.yaml') in text
    assert expected in text, text


def test_a_scene_parameter_the_scenario_schedule_overrides_is_refused(tmp_path):
    write(tmp_path, """\
        scene: conveyor
        duration: 2.0
        setpoint: 55.0
        load: {initial: 8.0}
        """, 'fixed_load.yaml')
    text = error_of(tmp_path, "scenario: fixed_load.yaml\nvary: {load.torque: [4.0, 8.0]}\n")
    assert "case 0 (load.torque = 4.0): load.torque = 4.0 does not reach the device" in text
    # a load schedule with changes: the varied load would hold only until the first one
    text = error_of(tmp_path, "scenario: conveyor_load_step\nvary: {load.torque: [4.0, 8.0]}\n")
    assert ("case 0 (load.torque = 4.0): load.torque = 4.0 holds only until t = 4 s: the "
            "scenario's load schedule changes it then") in text, text


def test_numbers_written_as_yaml_1_1_text_are_numbers(tmp_path):
    campaign = load_campaign(write(tmp_path, """\
        scene: conveyor
        duration: 1
        sample_dt: 1e-3
        vary: {shaft.stiffness: {range: [2e2, 1.0e5], num: 2}}
        """))
    assert campaign.sample_dt == 1e-3 and campaign.variables[0].grid() == [200.0, 100000.0]


def test_cli_refuses_a_large_campaign_without_yes_before_anything_runs(tmp_path):
    path = write(tmp_path, """\
        scene: conveyor
        duration: 1
        vary:
          load.torque: {range: [0, 10], num: 50}
          linkage.crank_length: {range: [0.01, 0.09], num: 50}
        """)
    out = tmp_path / 'out'
    proc = subprocess.run([sys.executable, '-m', 'cvt_ros', 'sweep', str(path), '--out', str(out),
                           '--max-cases', '100'], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2
    assert '2,500 cases, more than --max-cases 100' in proc.stderr and '--yes' in proc.stderr
    assert len(proc.stderr.strip().splitlines()) == 1 and not out.exists()
    proc = subprocess.run([sys.executable, '-m', 'cvt_ros', 'sweep', str(path), '--out', str(out),
                           '--max-cases', '100', '--yes', '--dry-run'], capture_output=True,
                          text=True, timeout=120)
    assert proc.returncode == 0 and '2500 cases' in proc.stdout and not out.exists()


def test_cli_a_local_cluster_that_cannot_start_is_one_clear_error(tmp_path):
    """--dashboard with a host that does not resolve: LocalCluster raises RuntimeError; that
    was a 57-line traceback and exit 1 (the code of 'some cases failed')."""
    path = write(tmp_path, """\
        scene: conveyor
        duration: 1
        vary: {load.torque: [4.0]}
        """)
    proc = subprocess.run([sys.executable, '-m', 'cvt_ros', 'sweep', str(path), '--out',
                           str(tmp_path / 'out'), '--workers', '1', '--dashboard',
                           'no-such-host.invalid:8787'], capture_output=True, text=True,
                          timeout=300)
    assert proc.returncode == 2, proc.stderr
    assert 'Traceback' not in proc.stderr
    assert 'cannot start a local cluster (dashboard at no-such-host.invalid:8787)' in proc.stderr


def test_a_shipped_campaign_by_name_from_any_folder(tmp_path, monkeypatch):
    """As scenes and scenarios: `cvt-sim sweep conveyor_ratio_map` was 'No such file'."""
    monkeypatch.chdir(tmp_path)
    campaign = load_campaign('conveyor_ratio_map')
    assert campaign.name == 'conveyor_ratio_map' and campaign.path.name == 'conveyor_ratio_map.yaml'
    with pytest.raises(CampaignError, match='nowhere.yaml'):
        load_campaign('nowhere.yaml')
