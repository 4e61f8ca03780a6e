"""One check for every number a scenario file gives: finite, in range, whole where it must be;
the error (the caller's class) names the key, the value and the limit."""
import math


def number(value, key, low=-math.inf, high=math.inf, *, unit='', open_low=False, integer=False,
           error=ValueError):
    """``value`` as float (int with ``integer``) if it is a finite number in [low, high]
    ((low, high] with ``open_low``); else ``error(message)``."""
    units = f" [{unit}]" if unit else ''
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise error(f"{key}: expected a number{units}, got {value!r}")
    if not math.isfinite(value):
        raise error(f"{key}: {value!r} is not a finite number")
    if integer and value != int(value):
        raise error(f"{key}: expected a whole number, got {value!r}")
    if value < low or value > high or (open_low and value <= low):
        raise error(f"{key}: {value:g}{f' {unit}' if unit else ''} is outside "
                    f"{'(' if open_low else '['}{low:g}, {high:g}]")
    return int(value) if integer else float(value)
