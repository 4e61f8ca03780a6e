"""A scenario run as an MCAP recording (rosbag2 format, as the node records): joint_states every
control period, clutch_engaged at each switch's exact time, /clock, the crank-length commands the
controller gave and the load commands of the schedule at the period they took effect, and the
set point on ``/setpoint`` (std_msgs/Float64, at t = 0 and at each change), and of a realtime
run over DDS the node's /diagnostics (its timing: missed deadlines, jitter). ``cvt-sim analyze``,
``cvt-sim replay`` and the mcap/rosbags libraries read it like any recording of the node."""
import numpy as np

from ..analysis.bag import SETPOINT_TOPIC
from ..interface import QOS, float64_cdr, stamp_ns
from ..recording.errors import RecordingError
from ..recording.recorder import SimulationRecorder, check_target
from ..solver.output import COL

SETPOINT_TYPE = 'std_msgs/msg/Float64'
SETPOINT_QOS = dict(QOS['crank_length_cmd'])


def write_mcap(run, path, overwrite=False):
    """Write ``run`` (a ScenarioRun) to ``path``; returns (messages, error or None)."""
    errors = []
    sc = run.scenario
    try:
        check_target(path, overwrite)
        recorder = SimulationRecorder(
            path, parameters=dict(run.scenario.values), scene=str(sc.scene),
            source=f"cvt-sim scenario run {sc.path} ({run.backend_text})", overwrite=overwrite,
            extra_topics=[(SETPOINT_TOPIC, SETPOINT_TYPE, SETPOINT_QOS)],
            on_error=errors.append)
    except RecordingError as exc:
        return 0, exc
    samples = run.samples
    t = samples[:, COL['t']]
    commands = run.commands
    load_change = np.flatnonzero(np.diff(run.load) != 0) + 1
    setpoint_change = set((np.flatnonzero(np.diff(run.setpoint) != 0) + 1).tolist()) | {0}
    load_change = set(load_change.tolist())
    switches = run.switches
    diagnostics = run.diagnostics
    count, j, d = 0, 0, 0
    with recorder:
        count += recorder.record_clutch_state(bool(samples[0, COL['engaged']]), t[0])
        for k, row in enumerate(samples):
            ns = stamp_ns(row[0])
            while j < len(switches) and stamp_ns(switches[j][0]) <= ns:
                count += recorder.record_clutch_state(switches[j][1], switches[j][0])
                j += 1
            while d < len(diagnostics) and stamp_ns(diagnostics[d][0]) <= ns:
                count += recorder.write(recorder.topics['diagnostics'], diagnostics[d][1],
                                        stamp_ns(diagnostics[d][0]))
                d += 1
            if not recorder.record_sample(row):
                break
            count += 1 + recorder.record_clock(row[0])
            if k in setpoint_change:
                count += recorder.write(SETPOINT_TOPIC, float64_cdr(run.setpoint[k]), ns)
            if k in load_change:
                count += recorder.record_command('load_torque_cmd', float(run.load[k]), row[0])
            if k < len(commands) and np.isfinite(commands[k]):
                count += recorder.record_command('crank_length_cmd', float(commands[k]), row[0])
        if run.self_check is not None:
            recorder.record_self_check(run.self_check)
    return count, (errors[0] if errors else None)
