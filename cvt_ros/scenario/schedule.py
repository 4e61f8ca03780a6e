"""Schedules: a signal of simulation time (set point, load torque) as an initial value and changes.

A schedule in a scenario file::

    load:
      initial: 8.0                        # value at t = 0 (default: the scene's value)
      changes:
        - {at: 10.0, step: 14.0}                                 # jump to 14 at t = 10 s
        - {at: 15.0, ramp: {to: 8.0, duration: 2.0}}             # linear, 15 s → 17 s
        - {at: 20.0, sine: {amplitude: 2.0, frequency: 0.5, duration: 4.0}}   # added to the level
        - {at: 30.0, profile: {file: belt_load.csv, column: load_torque}}     # recorded

Semantics: the *level* starts at ``initial``; a step sets it; a ramp moves it linearly to ``to``
over ``duration``; a sine adds ``amplitude·sin(2π·frequency·(t − at) + phase)`` to the level for
``duration`` (the level is unchanged after it); a profile plays a CSV recording (its time column
relative to ``at``, linear interpolation) and the level holds its last value after it. Changes
are in time order and may not overlap (a change starting while a ramp, sine or profile still
runs is an error), and every change ends by the scenario's duration.

Schedules are evaluated on the control-period grid once, before a run (:meth:`Schedule.sample`):
the harness then reads an array, and every back end sees the same numbers.
"""
import csv
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..yaml_file import InputFileError, read_text
from .checks import number

KINDS = ('step', 'ramp', 'sine', 'profile')
MAX_PROFILE_ROWS = 1_000_000
MAX_PROFILE_BYTES = 64 << 20     # a million rows of two numbers fit well


class ScheduleError(ValueError):
    """A schedule that cannot be used; the message names the key, the value and the limit."""


@dataclass(frozen=True, eq=False)
class Change:
    """One change of a schedule: start time [s], kind, and the kind's numbers."""
    at: float
    kind: str
    value: float = math.nan          # step: new level; ramp: target level
    duration: float = 0.0            # ramp, sine, profile [s]
    amplitude: float = 0.0           # sine
    frequency: float = 0.0           # sine [Hz]
    phase: float = 0.0               # sine [rad]
    times: np.ndarray = None         # profile: times relative to ``at`` [s]
    values: np.ndarray = None        # profile values
    source: str = ''                 # profile: file (and column) it came from
    file: str = ''                   # profile: the file it came from

    @property
    def end(self):
        return self.at + self.duration


@dataclass(frozen=True, eq=False)
class Schedule:
    """A piecewise signal: ``initial`` then ``changes`` (time order, no overlap)."""
    initial: float
    changes: tuple = field(default_factory=tuple)

    def sample(self, t):
        """The signal at the times ``t`` (array) → array of the same shape. Each change fills
        only the times up to the next change's start (found by bisection), so the cost is
        O(len(t) + changes), not their product (5000 changes over a day's grid)."""
        t = np.asarray(t, dtype=float)
        shape, t = t.shape, t.ravel()
        order = None
        if t.size > 1 and np.any(t[1:] < t[:-1]):   # (callers pass increasing times)
            order = np.argsort(t, kind='stable')
            t = t[order]
        out = np.full(t.shape, float(self.initial))
        level = float(self.initial)
        starts = np.searchsorted(t, [c.at for c in self.changes], side='left').tolist()
        starts.append(t.size)
        for c, i0, i1 in zip(self.changes, starts, starts[1:], strict=False):
            seg = t[i0:i1]        # from this change's start to the next one's
            if c.kind == 'step':
                level = c.value
                out[i0:i1] = level
            elif c.kind == 'ramp':
                frac = np.clip((seg - c.at) / c.duration, 0.0, 1.0) if c.duration > 0 \
                    else np.ones(seg.size)
                out[i0:i1] = level + (c.value - level) * frac
                level = c.value
            elif c.kind == 'sine':
                on = seg < c.end
                out[i0:i1] = level
                out[i0:i1][on] += c.amplitude * np.sin(2.0 * math.pi * c.frequency
                                                       * (seg[on] - c.at) + c.phase)
            else:  # profile
                out[i0:i1] = np.interp(seg - c.at, c.times, c.values)
                level = float(c.values[-1])
        if order is not None:
            unsorted = np.empty_like(out)
            unsorted[order] = out
            out = unsorted
        return out.reshape(shape)

    def change_times(self):
        """Start times of the changes [s] (where a step response begins)."""
        return [c.at for c in self.changes]

    def final_value(self):
        return float(self.sample(np.array([math.inf]))[0]) if self.changes else self.initial


# ------------------------------------------------------------------------------- parsing
def _number(value, key, low=-math.inf, high=math.inf, unit='', open_low=False):
    return number(value, key, low, high, unit=unit, open_low=open_low, error=ScheduleError)


def _only_keys(body, allowed, key):
    if not isinstance(body, dict):
        raise ScheduleError(f"{key}: expected a map, got {body!r}")
    unknown = sorted(set(body) - set(allowed))
    if unknown:
        raise ScheduleError(f"{key}: unknown key {unknown[0]!r}; allowed: "
                            f"{', '.join(allowed)}")


def parse_schedule(body, key, duration, initial=None, limits=(-math.inf, math.inf), unit='',
                   base_dir=Path('.'), truncate=False):
    """A schedule from its scenario-file form (see the module docstring); ``key`` names it in
    errors (``load``), ``initial`` is the default start value, ``limits`` bound every value the
    signal takes, ``base_dir`` is where profile files are looked up. ``truncate``: the duration
    was shortened on purpose (``--duration``): changes past it are dropped, not refused."""
    if isinstance(body, (int, float)) and not isinstance(body, bool):
        body = {'initial': body}          # a constant: `setpoint: 55.0`
    _only_keys(body, ('initial', 'changes'), key)
    lo, hi = limits
    if 'initial' in body:
        initial = _number(body['initial'], f"{key}.initial", lo, hi, unit)
    elif initial is None:
        raise ScheduleError(f"{key}.initial: missing (the value at t = 0 [{unit}])")
    raw = body.get('changes') or []
    if not isinstance(raw, list):
        raise ScheduleError(f"{key}.changes: expected a list of changes, got {raw!r}")
    changes = []
    busy_until, busy_key = 0.0, None
    for i, item in enumerate(raw):
        ckey = f"{key}.changes[{i}]"
        change = _parse_change(item, ckey, math.inf if truncate else duration, lo, hi, unit,
                               base_dir)
        if change.at >= duration:
            continue
        if changes and change.at < changes[-1].at:
            raise ScheduleError(f"{ckey}.at: {change.at:g} s comes before the previous change "
                                f"({changes[-1].at:g} s); list changes in time order")
        if change.at < busy_until:
            raise ScheduleError(f"{ckey}.at: {change.at:g} s starts while {busy_key} still runs "
                                f"(until {busy_until:g} s)")
        busy_until, busy_key = change.end, ckey
        changes.append(change)
    schedule = Schedule(float(initial), tuple(changes))
    _check_range(schedule, key, duration, lo, hi, unit)
    return schedule


def _parse_change(item, key, duration, lo, hi, unit, base_dir):
    if not isinstance(item, dict):
        raise ScheduleError(f"{key}: expected a map such as {{at: 2.0, step: 10.0}}, got "
                            f"{item!r}")
    kinds = [k for k in KINDS if k in item]
    if len(kinds) != 1:
        raise ScheduleError(f"{key}: give exactly one of {', '.join(KINDS)} (found "
                            f"{', '.join(kinds) or 'none'})")
    kind = kinds[0]
    _only_keys(item, ('at', kind), key)
    if 'at' not in item:
        raise ScheduleError(f"{key}.at: missing (the start time [s])")
    at = _number(item['at'], f"{key}.at", 0.0, math.inf, 's')
    if at >= duration:
        raise ScheduleError(f"{key}.at: {at:g} s is at or past the scenario's duration "
                            f"({duration:g} s)")
    body, bkey = item[kind], f"{key}.{kind}"
    if kind == 'step':
        return Change(at, kind, value=_number(body, bkey, lo, hi, unit))
    if kind == 'ramp':
        _only_keys(body, ('to', 'duration'), bkey)
        for need in ('to', 'duration'):
            if need not in body:
                raise ScheduleError(f"{bkey}.{need}: missing")
        change = Change(at, kind, value=_number(body['to'], f"{bkey}.to", lo, hi, unit),
                        duration=_number(body['duration'], f"{bkey}.duration", 0.0, math.inf,
                                         's', open_low=True))
    elif kind == 'sine':
        _only_keys(body, ('amplitude', 'frequency', 'duration', 'phase'), bkey)
        for need in ('amplitude', 'frequency', 'duration'):
            if need not in body:
                raise ScheduleError(f"{bkey}.{need}: missing")
        change = Change(at, kind,
                        amplitude=_number(body['amplitude'], f"{bkey}.amplitude", 0.0, math.inf,
                                          unit),
                        frequency=_number(body['frequency'], f"{bkey}.frequency", 0.0, 1e4,
                                          'Hz', open_low=True),
                        duration=_number(body['duration'], f"{bkey}.duration", 0.0, math.inf,
                                         's', open_low=True),
                        phase=_number(body.get('phase', 0.0), f"{bkey}.phase", -1e3, 1e3,
                                      'rad'))
    else:
        change = _parse_profile(body, bkey, at, lo, hi, unit, base_dir)
    if change.end > duration * (1.0 + 1e-12):
        raise ScheduleError(f"{bkey}: runs until {change.end:g} s, past the scenario's "
                            f"duration ({duration:g} s)")
    return change


def _parse_profile(body, key, at, lo, hi, unit, base_dir):
    if isinstance(body, str):
        body = {'file': body}
    _only_keys(body, ('file', 'column', 'time_column'), key)
    if 'file' not in body or not isinstance(body['file'], str):
        raise ScheduleError(f"{key}.file: missing (a CSV file with a time column and a value "
                            f"column)")
    path = Path(body['file'])
    if not path.is_absolute():
        path = base_dir / path
    time_column = body.get('time_column', 't')
    times, values, column = read_profile(path, time_column, body.get('column'), key)
    for j, v in enumerate(values):
        if not (lo <= v <= hi):
            raise ScheduleError(f"{key}: {path} row {j + 2}: {column} = {v:g}"
                                f"{f' {unit}' if unit else ''} is outside [{lo:g}, {hi:g}]")
    return Change(at, 'profile', duration=float(times[-1]), times=times, values=values,
                  source=f"{path}:{column}", file=str(path))


def read_profile(path, time_column='t', column=None, key='profile'):
    """A recorded profile: (times from 0 [s], values, value column name) from a CSV file with a
    header line. ``column`` None: the one column besides the time column."""
    try:   # (a regular file of bounded size: a FIFO or /dev/zero is refused, not read)
        text = read_text(path, limit=MAX_PROFILE_BYTES, kind='a CSV file')
        rows = list(csv.reader(line for line in text.splitlines()
                               if not line.lstrip().startswith('#')))
    except InputFileError as exc:
        raise ScheduleError(f"{key}.file: {exc}") from None
    except csv.Error as exc:
        raise ScheduleError(f"{key}.file: {path} is not a CSV text file ({exc})") from None
    if len(rows) < 3:
        raise ScheduleError(f"{key}.file: {path} needs a header line and at least 2 rows")
    if len(rows) > MAX_PROFILE_ROWS:
        raise ScheduleError(f"{key}.file: {path} has {len(rows)} rows, more than "
                            f"{MAX_PROFILE_ROWS}")
    header = [h.strip() for h in rows[0]]
    if time_column not in header:
        raise ScheduleError(f"{key}.time_column: {path} has no column {time_column!r} (columns:"
                            f" {', '.join(header)})")
    others = [h for h in header if h != time_column]
    if column is None:
        if len(others) != 1:
            raise ScheduleError(f"{key}.column: {path} has columns {', '.join(others)}; name "
                                f"the one to play")
        column = others[0]
    if column not in header:
        raise ScheduleError(f"{key}.column: {path} has no column {column!r} (columns: "
                            f"{', '.join(header)})")
    ti, vi = header.index(time_column), header.index(column)
    data = np.empty((len(rows) - 1, 2))
    for j, row in enumerate(rows[1:]):
        try:
            data[j] = float(row[ti]), float(row[vi])
        except (IndexError, ValueError):
            raise ScheduleError(f"{key}.file: {path} row {j + 2}: not two numbers in columns "
                                f"{time_column!r}, {column!r}: {row!r}") from None
    bad = np.flatnonzero(~np.isfinite(data).all(axis=1))
    if len(bad):
        raise ScheduleError(f"{key}.file: {path} row {bad[0] + 2}: {data[bad[0]].tolist()} is "
                            f"not finite")
    times = data[:, 0] - data[0, 0]
    steps = np.diff(times)
    if np.any(steps <= 0):
        j = int(np.flatnonzero(steps <= 0)[0])
        raise ScheduleError(f"{key}.file: {path} row {j + 3}: time {data[j + 1, 0]:g} s does "
                            f"not increase")
    return times, data[:, 1].copy(), column


def _check_range(schedule, key, duration, lo, hi, unit):
    """Ramps and steps are checked one by one; a sine on a level can leave the range."""
    for i, c in enumerate(schedule.changes):
        if c.kind != 'sine':
            continue
        t = np.linspace(c.at, c.end, 257)
        v = schedule.sample(t)
        if v.min() < lo or v.max() > hi:
            bad = v.min() if v.min() < lo else v.max()
            raise ScheduleError(f"{key}.changes[{i}].sine: the signal reaches {bad:g}"
                                f"{f' {unit}' if unit else ''}, outside [{lo:g}, {hi:g}]")
