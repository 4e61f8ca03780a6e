"""What the controller launch file (launch/cvt_controller.launch.py) needs from a scenario,
written as plain files, so the launch file stays a thin list of nodes: the device's parameters
(every scene value, time mode, control period, recording), the reference controller's settings
and its set-point file, and the linkage geometry for the marker node. No launch import here."""
import os
from dataclasses import dataclass

import numpy as np

from ..device.descriptors import REALTIME_SOLVER
from ..scene import read_scene
from .dds import node_parameters, write_params_file
from .model import load_scenario
from .plants import plant_values


@dataclass(frozen=True)
class LaunchFiles:
    device_params: str          # params file of cvt_node
    setpoint_file: str          # CSV t,setpoint for cvt_speed_controller
    controller: dict            # cvt_speed_controller parameters (gains, limits)
    geometry: dict              # cvt_linkage_markers parameters
    scenario: object


def prepare(scenario, out_dir, time_mode='realtime', real_time_factor=1.0, record=''):
    """Write the files for ``scenario`` (name or path) into ``out_dir``; returns LaunchFiles."""
    sc = load_scenario(scenario)
    os.makedirs(out_dir, exist_ok=True)
    params = node_parameters(plant_values(sc), sc.control_period, time_mode, real_time_factor)
    if time_mode == 'realtime' and 'solver.method' not in {**read_scene(sc.scene),
                                                           **sc.overrides}:
        # as cvt_node itself does when nothing names the solver: a fixed cost per period
        params['solver.method'] = REALTIME_SOLVER
    params['record.path'] = record
    device_params = os.path.join(out_dir, f"{sc.name}_device.yaml")
    write_params_file(device_params, params)
    setpoint_file = os.path.join(out_dir, f"{sc.name}_setpoint.csv")
    grid = sc.time_grid()
    np.savetxt(setpoint_file, np.column_stack([grid, sc.setpoint.sample(grid)]), delimiter=',',
               header='t,setpoint', comments='', fmt='%.17g')
    from ..control.speed_pi import reference_controller
    g = reference_controller(sc).gains
    controller = {k: float(getattr(g, k)) for k in ('kp', 'ki', 'crank_min', 'crank_max',
                                                      'rate_limit', 'tracking_time')}
    controller['setpoint'] = float(sc.setpoint.initial)
    v = sc.values
    geometry = {'rocker_length': v['linkage.rocker_length'],
                'coupler_length': v['linkage.coupler_length'],
                'pivot_distance': v['linkage.pivot_distance']}
    return LaunchFiles(device_params, setpoint_file, controller, geometry, sc)
