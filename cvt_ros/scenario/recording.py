"""A scenario run as an MCAP recording (rosbag2 format, as the node records): joint_states every
control period, clutch_engaged at each switch's exact time, /clock, the crank-length commands the
controller gave and the load commands of the schedule at the period they took effect, and the
set point on ``/setpoint`` (std_msgs/Float64, at t = 0 and at each change), and of a realtime
run over DDS the node's /diagnostics (its timing: missed deadlines, jitter). ``cvt-sim analyze``,
``cvt-sim replay`` and the mcap/rosbags libraries read it like any recording of the node.

:class:`ScenarioRecording` writes it block by block as the run goes (``run_scenario(...,
mcap=PATH)``: the harness's stream, scenario/stream.py); :func:`write_mcap` writes a finished run
that kept every sample."""
import numpy as np

from ..analysis.bag import SETPOINT_TOPIC
from ..interface import QOS, float64_cdr, stamp_ns
from ..recording.errors import RecordingError
from ..recording.recorder import SimulationRecorder, check_target
from ..solver.clutch_sets import path_masks, set_changes
from ..solver.output import COL, N_COLUMNS

SETPOINT_TYPE = 'std_msgs/msg/Float64'
SETPOINT_QOS = dict(QOS['crank_length_cmd'])


def _time(switch):
    return switch[0] if isinstance(switch, tuple) else switch.t


class ScenarioRecording:
    """The recording of one scenario run, fed block by block (:meth:`block`, in time order).
    Raises RecordingError if the file cannot be created; an I/O error later stops the recording
    (``error``), not the run."""

    def __init__(self, scenario, path, overwrite=False, backend_text=''):
        self.errors = []
        check_target(path, overwrite)
        self.recorder = SimulationRecorder(
            path, parameters=dict(scenario.values), scene=str(scenario.scene),
            source=f"cvt-sim scenario run {scenario.path} ({backend_text})", overwrite=overwrite,
            extra_topics=[(SETPOINT_TOPIC, SETPOINT_TYPE, SETPOINT_QOS)],
            on_error=self.errors.append)
        self.count = 0
        self.stopped = False
        self.setpoint = self.load = None   # the last sample's (a change is recorded)
        self.mask = None                   # N ≥ 2 paths: the engaged set so far

    @property
    def error(self):
        return self.errors[0] if self.errors else None

    def block(self, samples, setpoint, load, commands, switches, diagnostics):
        """Samples (rows) with the schedules and the command given at each (NaN: none), and the
        switches ((t, engaged); N ≥ 2 paths (t, engaged, path)) and /diagnostics ((t, CDR
        bytes)) up to the last sample."""
        if self.stopped:
            return
        recorder = self.recorder
        count, j, d = 0, 0, 0
        n = recorder.n_paths
        if self.setpoint is None:
            t0 = samples[0, COL['t']]
            if n > 1:   # one switching instant at a time (recorder.record_switch), from the
                # first set
                self.mask = path_masks(samples[0, N_COLUMNS + 2 * n:N_COLUMNS + 3 * n])
                count += recorder.record_clutch_set(self.mask, t0)
            count += recorder.record_clutch_state(bool(samples[0, COL['engaged']]), t0)
        if n > 1:
            switches, self.mask = set_changes(switches, self.mask)
        given = np.isfinite(commands)
        for k, row in enumerate(samples):
            ns = stamp_ns(row[0])
            while j < len(switches) and stamp_ns(_time(switches[j])) <= ns:
                count += (recorder.record_switch(switches[j]) if n > 1
                          else recorder.record_clutch_state(switches[j][1], switches[j][0]))
                j += 1
            while d < len(diagnostics) and stamp_ns(diagnostics[d][0]) <= ns:
                count += recorder.write(recorder.topics['diagnostics'], diagnostics[d][1],
                                        stamp_ns(diagnostics[d][0]))
                d += 1
            if not recorder.record_sample(row):
                self.stopped = True
                break
            count += 1 + (n > 1) + recorder.record_clock(row[0])
            if setpoint[k] != self.setpoint:
                count += recorder.write(SETPOINT_TOPIC, float64_cdr(setpoint[k]), ns)
                self.setpoint = setpoint[k]
            if self.load is not None and load[k] != self.load:
                count += recorder.record_command('load_torque_cmd', float(load[k]), row[0])
            self.load = load[k]
            if given[k]:
                count += recorder.record_command('crank_length_cmd', float(commands[k]), row[0])
        self.count += count

    def finish(self, self_check=None):
        """Close the file (the solver's self-check in its metadata); (messages, error or None)."""
        if self_check is not None:
            self.recorder.record_self_check(self_check)
        self.recorder.close()
        return self.count, self.error


def write_mcap(run, path, overwrite=False):
    """Write ``run`` (a ScenarioRun that kept every sample) to ``path``; returns (messages,
    error or None). A long run keeps a thinned trace: record it as it runs
    (``run_scenario(..., mcap=PATH)``)."""
    if run.sample_stride != 1:
        return 0, RecordingError(f"{path}: the run kept every {run.sample_stride}th sample "
                                 f"only; record it while it runs (run_scenario(..., mcap=PATH), "
                                 f"cvt-sim scenario run --mcap)")
    try:
        recording = ScenarioRecording(run.scenario, path, overwrite, run.backend_text)
    except RecordingError as exc:
        return 0, exc
    recording.block(run.samples, run.setpoint, run.load, run.commands, run.switches,
                    run.diagnostics)
    return recording.finish(run.self_check)
