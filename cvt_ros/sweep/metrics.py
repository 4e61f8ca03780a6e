"""The figures a campaign keeps per case, computed by the analysis room's own functions.

**Scene campaigns** (open loop): the metric window is the detected steady state
(:func:`cvt_ros.analysis.steady.find_steady_state`: the cycle means settled within ±0.5 % for
≥ 10 crank cycles) or the whole crank cycles from a given time on; figures over it come from
:meth:`cvt_ros.analysis.cycles.CycleTable.window`. A run with no steady state gives its figures
over the last half of its cycles, ``steady`` False and a warning that says why. The energy
residual is the solver's own ledger over the whole run (exact, not sampled:
:func:`cvt_ros.solver.offline.summarize`).

**Scenario campaigns** (closed loop): the controller kit's step metrics
(:mod:`cvt_ros.analysis.stepinfo`, run level: the worst step; with ``window: {start: T}`` over
the steps from T on) and the energy residual.
"""
import math

import numpy as np

from ..analysis.cycles import UNPHYSICAL_NOTES, cycle_metrics, physical
from ..analysis.path_metrics import path_metrics
from ..analysis.steady import find_steady_state
from ..analysis.stepinfo import METRICS as STEP_METRICS
from ..analysis.trace import trace_of_samples
from ..solver.offline import summarize

#: name → (unit, meaning); the order of the table's columns
SCENE_METRICS = {
    'mean_ratio': ('-', 'ratio Δφ4/Δφ1 over the metric window (whole crank cycles)'),
    'efficiency': ('-', 'output work / motor work over the window'),
    'peak_clutch_torque': ('N*m', 'largest sampled clutch torque in the window'),
    'switches_per_second': ('1/s', 'clutch switches (engage + release) per second in the window'),
    'energy_residual': ('-', "the solver's energy-balance residual / work, whole run"),
    'output_speed': ('rad/s', 'mean output speed ω4 over the window'),
    'crank_speed': ('rad/s', 'mean crank speed ω1 over the window'),
    'ripple': ('-', 'output speed ripple (max − min) / mean, per cycle, mean over the window'),
    'load_factor': ('-', 'dynamic load factor: peak / mean clutch torque'),
    'twist_peak': ('rad', 'largest shaft twist in the window'),
    'engaged_fraction': ('-', 'time the clutch is engaged / window length'),
    'motor_power': ('W', 'mean motor power over the window'),
    'output_power': ('W', 'mean power taken by the load over the window'),
    'run_peak_clutch_torque': ('N*m', 'largest sampled clutch torque of the whole run '
                                      '(start-up included)'),
    # N paths (issue 33): what one clutch carries (= the totals above for one path)
    'peak_path_clutch_torque': ('N*m', 'largest sampled torque of any one clutch in the window '
                                       '(the most loaded path\'s)'),
    'path_engaged_fraction': ('-', 'time one clutch is engaged / window length, the mean over '
                                   'the paths'),
    'run_peak_path_clutch_torque': ('N*m', 'largest sampled torque of any one clutch in the '
                                           'whole run (start-up included)'),
}
#: per-path figures (analysis.path_metrics) behind the path metrics: (figure, reduction)
_FROM_PATHS = {'peak_path_clutch_torque': ('clutch_torque_peak', max),
               'path_engaged_fraction': ('engaged_fraction', lambda v: sum(v) / len(v))}
_FROM_WINDOW = {'mean_ratio': 'ratio', 'efficiency': 'efficiency',
                'peak_clutch_torque': 'clutch_torque_peak', 'output_speed': 'output_speed',
                'crank_speed': 'crank_speed', 'ripple': 'ripple', 'load_factor': 'load_factor',
                'twist_peak': 'twist_peak', 'engaged_fraction': 'engaged_fraction',
                'motor_power': 'motor_power', 'output_power': 'output_power'}
SCENARIO_METRICS = {**{name: (unit, 'step metric (analysis/stepinfo.py), worst step')
                       for name, unit in STEP_METRICS.items()},
                    'energy_residual': SCENE_METRICS['energy_residual']}
#: the columns every scene case has besides its metrics: where its window is and whether it
#: is a steady state
WINDOW_COLUMNS = {'steady': ('-', 'the window is a detected steady state'),
                  'window_start': ('s', 'start of the metric window')}
REQUIRED = ('mean_ratio', 'efficiency', 'peak_clutch_torque', 'switches_per_second',
            'energy_residual')


def default_metrics(kind):
    if kind == 'scene':
        return REQUIRED + ('output_speed',)
    return tuple(SCENARIO_METRICS)


def trace_of_run(values, result):
    """A finished ``Simulator.run`` as an analysis Trace (true state, exact switch times)."""
    return trace_of_samples(result.samples, result.columns, result.switches,
                            source='sweep case', kind='sweep', parameters=dict(values))


def _path_figures(trace, figures):
    """Per-path figures over the window (whole run without one); one path: the machine's own
    (its one clutch)."""
    if trace.paths is None:
        return [{'engaged_fraction': figures.get('engaged_fraction', math.nan),
                 'clutch_torque_peak': figures.get('clutch_torque_peak', math.nan)}]
    return path_metrics(trace, figures.get('t_start'), figures.get('t_end'))


def _window(cycles, window):
    """(first cycle, steady?, why not) of the metric window."""
    n = len(cycles)
    if window != 'steady':
        first = int(np.searchsorted(cycles['t_start'], float(window) - 1e-12))
        return first, False, '' if first < n else f"no whole crank cycle after {window:g} s"
    steady = find_steady_state(cycles)
    if steady.found:
        return steady.first, True, ''
    return n // 2, False, (f"no steady state ({steady.reason}): figures over the last half of "
                           f"the {n} crank cycles")


def scene_metrics(values, result, duration, window, names):
    """(figures by name + the window columns, warnings) of one scene case."""
    summary = summarize(result, duration)
    out = dict.fromkeys(names, math.nan)
    warnings = list(summary['warnings']) + list(result.diagnostics.get('warnings', ()))
    with np.errstate(all='ignore'):
        trace = trace_of_run(values, result)
        cycles = cycle_metrics(trace)[0]
        first, steady, why = _window(cycles, window)
        figures = cycles.window(first, len(cycles)) if first < len(cycles) else {}
        if figures and set(_FROM_PATHS) & set(out):
            for name, (key, reduce) in _FROM_PATHS.items():
                if name in out:
                    out[name] = float(reduce([p[key] for p in _path_figures(trace, figures)]))
        if 'run_peak_path_clutch_torque' in out:
            out['run_peak_path_clutch_torque'] = max(summary.get(
                'peak_clutch_torque_per_path_Nm', [summary['peak_clutch_torque_Nm']]))
    if why:
        warnings.append(why)
    if figures:
        for name, key in _FROM_WINDOW.items():
            if name in out:
                out[name] = float(figures.get(key, math.nan))
                if not physical(key, out[name]):   # kept, but never as a plain number
                    warnings.append(f"{name} = {out[name]:.6g}: {UNPHYSICAL_NOTES[key]}")
        if 'switches_per_second' in out:
            span = figures['t_end'] - figures['t_start']
            out['switches_per_second'] = figures['switches_per_cycle'] * figures['cycles'] / span
    if 'energy_residual' in out:
        out['energy_residual'] = summary['energy_residual_relative']
    if 'run_peak_clutch_torque' in out:
        out['run_peak_clutch_torque'] = summary['peak_clutch_torque_Nm']
    out['steady'] = steady
    out['window_start'] = float(figures['t_start']) if figures else math.nan
    return out, warnings


def scenario_metrics(run, energy, names, since=0.0):
    """Figures by name of one scenario run (a ScenarioRun) and the plant's energy balance;
    ``since`` [s]: the steps from then on, and the whole-run figures over that span."""
    metrics = run.metrics_since(since)
    out = {name: float(metrics.get(name, math.nan)) for name in names
           if name != 'energy_residual'}
    if 'energy_residual' in names:
        out['energy_residual'] = float(energy.get('relative_residual', math.nan))
    return out


__all__ = ['REQUIRED', 'SCENARIO_METRICS', 'SCENE_METRICS', 'WINDOW_COLUMNS', 'default_metrics',
           'scenario_metrics', 'scene_metrics', 'trace_of_run']
