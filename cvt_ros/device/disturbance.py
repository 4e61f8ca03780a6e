"""A disturbance schedule given up front (parameter ``disturbance.file``): load torque steps that
land in a known control period, so a lockstep run over DDS is reproducible to the bit.

The file is CSV, one step per row, ``t,load_torque`` [s, N·m], times increasing, an optional
header ``t,load_torque``, ``#`` comments and blank lines ignored::

    t,load_torque
    0.0,8
    2.0,12     # from the period that starts at t_k = k·period >= 2.0 s

Row ``(t, M)`` is applied with ``Device.command_load_torque(M)`` at the start of the first control
period whose start time t_k = k·period (k counted from the reset) is ≥ t: the k·period grid the
controller kit's scenarios use, so a change at 2 s lands in period 2000 at 1 kHz, not at a sum of
2000 additions that may fall short of 2.0. Several rows due at one period: the last one wins.
"""
import math
from dataclasses import dataclass

from ..yaml_file import InputFileError, read_text

HEADER = ('t', 'load_torque')


class DisturbanceError(InputFileError):
    """A disturbance file that cannot be used: the message names the file, the line, the value
    and the limit."""


@dataclass(frozen=True)
class DisturbanceSchedule:
    """Load torque steps: ``times`` [s] increasing, ``values`` [N·m]; ``path`` for messages."""
    path: str
    times: tuple
    values: tuple

    @property
    def peak(self):
        """Largest |load torque| in the schedule [N·m] (0 when empty)."""
        return max((abs(v) for v in self.values), default=0.0)

    def check_limit(self, limit):
        """Raise DisturbanceError if a value exceeds ``limit`` (parameter limits.load_torque)."""
        for t, value in zip(self.times, self.values, strict=True):
            if abs(value) > limit:
                raise DisturbanceError(
                    f"{self.path}: load_torque {value!r} N*m at t = {t!r} s is beyond the limit "
                    f"|M| <= {limit!r} N*m (parameter limits.load_torque)")


def _number(text, path, line, what):
    try:
        value = float(text)
    except ValueError:
        raise DisturbanceError(f"{path}:{line}: {what} {text.strip()!r} is not a number") from None
    if not math.isfinite(value):
        raise DisturbanceError(f"{path}:{line}: {what} {text.strip()!r} is not a finite number")
    return value


def load_disturbance(path, limit=math.inf):
    """The schedule in ``path`` (see the module text); DisturbanceError naming the file, the
    line and the value otherwise (including a value beyond ``limit`` [N·m])."""
    text = read_text(path, DisturbanceError)
    times, values = [], []
    for line, raw in enumerate(text.splitlines(), start=1):
        content = raw.split('#', 1)[0].strip()
        if not content:
            continue
        fields = [f.strip() for f in content.split(',')]
        if not times and tuple(fields) == HEADER:
            continue
        if len(fields) != 2:
            raise DisturbanceError(f"{path}:{line}: expected 2 fields t,load_torque, got "
                                   f"{len(fields)}: {content!r}")
        try:
            t = _number(fields[0], path, line, 't')
            value = _number(fields[1], path, line, 'load_torque')
        except DisturbanceError as exc:
            if times:
                raise
            raise DisturbanceError(f"{exc} (the first row is the header "
                                   f"{','.join(HEADER)} or a step)") from None
        if t < 0.0:
            raise DisturbanceError(f"{path}:{line}: t {t!r} s is negative (times start at 0)")
        if times and t <= times[-1]:
            raise DisturbanceError(f"{path}:{line}: t {t!r} s does not increase (previous row "
                                   f"{times[-1]!r} s)")
        times.append(t)
        values.append(value)
    schedule = DisturbanceSchedule(str(path), tuple(times), tuple(values))
    schedule.check_limit(limit)
    return schedule


__all__ = ['DisturbanceError', 'DisturbanceSchedule', 'load_disturbance']
