"""One check for every number a scenario file gives: finite, in range, whole where it must be;
the error (the caller's class) names the key, the value and the limit."""
import math

from ..numbers import NotANumber, real_number, shown


def number(value, key, low=-math.inf, high=math.inf, *, unit='', open_low=False, integer=False,
           error=ValueError):
    """``value`` as float (int with ``integer``) if it is a finite number in [low, high]
    ((low, high] with ``open_low``); else ``error(message)``."""
    units = f" [{unit}]" if unit else ''
    if isinstance(value, bool) or not isinstance(value, (int, float)):   # (not text: '1e3')
        raise error(f"{key}: expected a number{units}, got {shown(value)}")
    try:
        x = real_number(value)
    except NotANumber as exc:   # a 400-digit integer
        raise error(f"{key}: {exc}; accepted: {'(' if open_low else '['}{low:g}, {high:g}]"
                    ) from None
    if not math.isfinite(x):
        raise error(f"{key}: {value!r} is not a finite number")
    if integer and x != int(x):
        raise error(f"{key}: expected a whole number, got {value!r}")
    whole = integer and isinstance(value, int)   # compared exactly: 2**63 vs 2**63 − 1
    exact = value if whole else x
    if exact < low or exact > high or (open_low and exact <= low):
        shown_value, shown_high = (f"{value}", f"{high}") if whole else (f"{x:g}", f"{high:g}")
        raise error(f"{key}: {shown_value}{f' {unit}' if unit else ''} is outside "
                    f"{'(' if open_low else '['}{low:g}, {shown_high}]")
    return int(value) if integer else x
