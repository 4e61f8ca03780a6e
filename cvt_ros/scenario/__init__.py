"""Controller test scenarios: scenario files, schedules, sensor/actuator realism, and the harness
that runs a controller against the device offline, in-process in lockstep, or over DDS.

    from cvt_ros.scenario import load_scenario, run_scenario
    run = run_scenario(load_scenario('conveyor_setpoint_steps'))   # the reference controller
    run.metrics['overshoot'], run.metrics['settling_time']
"""
from .harness import BACKENDS, HarnessError, load_controller, run_scenario
from .model import Scenario, ScenarioError, available_scenarios, load_scenario

__all__ = ['BACKENDS', 'HarnessError', 'Scenario', 'ScenarioError', 'available_scenarios',
           'load_controller', 'load_scenario', 'run_scenario']
