"""The device's health as /diagnostics reports it: counters the run loop keeps, and the key/value
table a DiagnosticStatus carries (docs/node.md, "Diagnostics"). No ROS here: the node wraps the
table in diagnostic_msgs.

Levels: OK, WARN (missed deadlines, resyncs, refused or lost commands in the last window; a
possibly missed clutch event since the start: the solver's self-check, docs/solver.md), ERROR
(a simulation fault). The "window" is the wall time since the previous report (~1 s).
"""
import math
import time
from dataclasses import dataclass, field

from .core import Ring

OK, WARN, ERROR = 0, 1, 2   # diagnostic_msgs/DiagnosticStatus levels


@dataclass
class Stats:
    """Counters the loop thread writes and the diagnostics timer reads."""
    samples: int = 0
    missed: int = 0
    resyncs: int = 0
    slipped_ns: int = 0
    lag_ns: int = 0
    switches: int = 0
    last_switch_t: float = math.nan
    commands: int = 0
    refused: int = 0
    dropped: int = 0
    lost: int = 0
    resets: int = 0
    jitter_ns: Ring = field(default_factory=Ring)


class Reporter:
    """Turns the loop's counters and its latest snapshot into one report per call, with rates
    over the window since the previous call."""

    def __init__(self):
        self.previous = None

    def report(self, snap, stats, step_ns, settings):
        """(level, message, [(key, text)]) or None before the first snapshot.

        ``snap``: Device.snapshot() plus 'wall_ns', 'samples', 'resets'; ``step_ns``: the
        device's step-time Ring; ``settings``: mode, state, real_time_factor, publish_rate,
        control_period, fault.
        """
        if not snap:
            return None
        now = time.monotonic_ns()
        cur = {'wall_ns': now, 't': snap['t'], 'samples': stats.samples,
               'switch_count': snap['switch_count'], 'missed': stats.missed,
               'resyncs': stats.resyncs, 'refused': stats.refused, 'lost': stats.lost,
               'dropped': stats.dropped, 'phi1': snap['phi1'],
               'phi4': snap['phi4'], 'resets': snap['resets'], 'snap_wall_ns': snap['wall_ns']}
        prev, self.previous = self.previous, cur
        rtf = rate = switch_rate = ratio = math.nan
        window_missed = window_refused = window_resyncs = window_lost = 0
        if prev is not None and prev['resets'] == cur['resets']:
            wall = (now - prev['wall_ns']) * 1e-9
            snap_wall = (cur['snap_wall_ns'] - prev['snap_wall_ns']) * 1e-9
            dt_sim = cur['t'] - prev['t']
            if snap_wall > 0:
                rtf = dt_sim / snap_wall
            if wall > 0:
                rate = (cur['samples'] - prev['samples']) / wall
            if dt_sim > 0:
                switch_rate = (cur['switch_count'] - prev['switch_count']) / dt_sim
            dphi1 = cur['phi1'] - prev['phi1']
            if dphi1 != 0:
                ratio = (cur['phi4'] - prev['phi4']) / dphi1
            window_missed = cur['missed'] - prev['missed']
            window_refused = cur['refused'] - prev['refused']
            window_resyncs = cur['resyncs'] - prev['resyncs']
            window_lost = cur['lost'] + cur['dropped'] - prev['lost'] - prev['dropped']
        step = step_ns.percentiles() or [math.nan] * 3
        jitter = stats.jitter_ns.percentiles() or [math.nan] * 3
        mode, state, fault = settings['mode'], settings['state'], settings['fault']
        check = snap.get('self_check') or {}
        missed_events = check.get('possible_missed_events', 0)
        first_missed = check.get('first_possible_missed_event_s') or math.nan
        realtime = mode == 'realtime'
        values = [
            ('time_mode', mode), ('state', state),
            ('sim_time', f"{snap['t']:.6f}"),
            ('real_time_factor', f"{rtf:.4g}"),
            ('real_time_factor_target', f"{settings['real_time_factor']:g}" if realtime else '-'),
            ('publish_rate', f"{rate:.6g}"),
            ('publish_rate_target', f"{settings['publish_rate'] * settings['real_time_factor']:g}"
                                    if realtime else '-'),
            ('control_period', f"{settings['control_period']:.9g}"),
            ('samples_published', str(snap['samples'])),   # with sim_time: one snapshot
            ('missed_deadlines', str(stats.missed)),
            ('missed_deadlines_last_window', str(window_missed)),
            ('lag_ms', f"{stats.lag_ns / 1e6:.3f}"),
            ('resyncs', str(stats.resyncs)),
            ('slipped_s', f"{stats.slipped_ns / 1e9:.3f}"),
            ('step_time_p50_us', f"{step[0] / 1e3:.1f}"),
            ('step_time_p99_us', f"{step[1] / 1e3:.1f}"),
            ('step_time_max_us', f"{step[2] / 1e3:.1f}"),
            ('jitter_p50_us', f"{jitter[0] / 1e3:.1f}"),
            ('jitter_p99_us', f"{jitter[1] / 1e3:.1f}"),
            ('jitter_max_us', f"{jitter[2] / 1e3:.1f}"),
            ('switches_per_second', f"{switch_rate:.4g}"),
            ('switches_total', str(snap['switch_count'])),
            ('last_switch_time', f"{stats.last_switch_t:.6f}"),
            ('clutch_engaged', str(snap['engaged']).lower()),
            ('energy_residual_J', f"{snap['residual']:.6g}"),
            ('energy_relative_residual', f"{snap['relative_residual']:.3g}"),
            ('ratio', f"{ratio:.5g}"),
            ('crank_length_m', f"{snap['crank_length']:.6g}"),
            ('crank_length_target_m', f"{snap['crank_target']:.6g}"),
            ('grashof_bound_m', f"{snap['grashof_bound']:.6g}"),
            ('load_torque_Nm', f"{snap['load_torque']:.6g}"),
            ('commands_received', str(stats.commands)),
            ('commands_refused', str(stats.refused)),
            ('commands_dropped', str(stats.dropped)),
            ('commands_lost', str(stats.lost)),
            ('realtime_policy', settings.get('policy', '')),
            ('solver', check.get('solver', '')),
            ('possible_missed_events', str(missed_events)),
            ('first_possible_missed_event_time', f"{first_missed:.6f}"),
            ('fault', fault or ''),
        ]
        n = snap.get('n_paths', 1)
        if n > 1:   # N paths (issue 33): which clutches hold now, each one's switches
            engaged = snap['engaged_set']
            values += [
                ('paths', str(n)),
                ('clutches_engaged', ','.join(str(k + 1) for k in range(n) if engaged >> k & 1)
                 or 'none'),
                ('switches_per_path', ','.join(str(c) for c in snap['path_switches'])),
            ]
        if fault:
            level, message = ERROR, f"simulation fault: {fault}"
        elif window_missed or window_resyncs:
            level = WARN
            message = (f"behind schedule: {window_missed} missed deadlines, {window_resyncs} "
                       f"resyncs in the last window")
        elif missed_events:
            level = WARN
            message = (f"{missed_events} possibly missed clutch events (first at t = "
                       f"{first_missed:.6f} s): the solver found a guard beyond its band after "
                       f"a step ({check.get('solver', '')}); a tighter solver.rtol or "
                       f"solver.fixed_step resolves it")
        elif window_lost:
            level, message = WARN, f"{window_lost} commands lost or dropped"
        elif window_refused:
            level, message = WARN, f"{window_refused} commands refused"
        else:
            level, message = OK, state
        return level, message, values


__all__ = ['ERROR', 'OK', 'Reporter', 'Stats', 'WARN']
