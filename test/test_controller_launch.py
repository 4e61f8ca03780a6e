"""The controller launch file and the Foxglove layout: the files a launch needs are built from a
scenario; the launch description builds where launch is importable; the layout shows topics the
device and the controller publish."""
import importlib.util
import json
from pathlib import Path

import numpy as np
import pytest
import yaml

from cvt_ros import interface
from cvt_ros.scenario.launch_files import prepare

ROOT = Path(__file__).resolve().parent.parent


def test_prepare_writes_what_the_nodes_read(tmp_path):
    files = prepare('conveyor_setpoint_steps', tmp_path, 'lockstep', 1.0, str(tmp_path / 'r.mcap'))
    doc = yaml.safe_load(Path(files.device_params).read_text())['cvt_sim']['ros__parameters']
    assert doc['time_mode'] == 'lockstep' and doc['publish_rate'] == 1000.0
    assert doc['record.path'] == str(tmp_path / 'r.mcap')
    assert doc['load.torque'] == 8.0 and doc['linkage.crank_length'] == 0.04
    from cvt_ros.control.node import read_setpoint_file
    times, values = read_setpoint_file(files.setpoint_file)
    assert len(times) == files.scenario.periods + 1
    assert values[0] == 55.0 and values[np.searchsorted(times, 2.0)] == 70.0
    assert files.controller['rate_limit'] == 0.01 and files.geometry['pivot_distance'] == 0.2
    assert doc['solver.method'] == 'dopri5'     # lockstep: the offline answer
    # realtime: a fixed cost per period, as cvt_node chooses when nothing names the solver
    live = prepare('conveyor_setpoint_steps', tmp_path / 'rt', 'realtime')
    doc = yaml.safe_load(Path(live.device_params).read_text())['cvt_sim']['ros__parameters']
    assert doc['solver.method'] == 'rk4' and doc['time_mode'] == 'realtime'


def test_launch_description_builds():
    pytest.importorskip('launch')
    pytest.importorskip('launch_ros')
    spec = importlib.util.spec_from_file_location(
        'cvt_controller_launch', ROOT / 'launch' / 'cvt_controller.launch.py')
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    description = module.generate_launch_description()
    names = [a.name for a in description.entities if hasattr(a, 'name')]
    assert names[:4] == ['scenario', 'time_mode', 'real_time_factor', 'record']


def test_launch_file_parses_without_launch():
    import ast
    tree = ast.parse((ROOT / 'launch' / 'cvt_controller.launch.py').read_text())
    functions = {n.name for n in tree.body if isinstance(n, ast.FunctionDef)}
    assert {'generate_launch_description', '_nodes'} <= functions


def test_foxglove_layout_uses_published_topics():
    layout = json.loads((ROOT / 'config' / 'foxglove' / 'cvt_controller.json').read_text())
    panels = layout['configById']
    assert any(k.startswith('3D!') for k in panels)
    topics = {'/' + interface.JOINT_STATES, '/' + interface.CRANK_LENGTH_CMD, '/setpoint',
              '/cvt_speed_controller/cycle_mean_speed', '/cvt_speed_controller/setpoint',
              '/linkage_markers'}
    for key, panel in panels.items():
        for path in panel.get('paths', []):
            assert path['value'].split('.')[0] in topics, (key, path['value'])
            # one time axis live and in recordings: a recording's log time is simulation time,
            # a live header stamp would be simulation time against the others' wall clock
            assert path['timestampMethod'] == 'receiveTime', (key, path['value'])
    assert '/linkage_markers' in panels['3D!cvt_linkage']['topics']

    def leaves(node):
        return [node] if isinstance(node, str) else leaves(node['first']) + leaves(
            node['second'])
    assert sorted(leaves(layout['layout'])) == sorted(panels)
