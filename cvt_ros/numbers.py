"""Numbers from outside — input files, command lines, a user's controller — as floats, with one
conversion and one kind of refusal for everything that is not a usable number.

Python's own ``float(x)`` is the wrong gate for input: it reads text (``'0.05'``) and booleans
(``True`` is 1.0), and it raises OverflowError for an integer beyond the float range (a 400-digit
literal in a YAML file), or whatever an object's ``__float__`` happens to raise.
:func:`real_number` accepts real numbers only (int, float, numpy's numbers, any
``numbers.Real``), never text or booleans, and turns every failure into a :class:`NotANumber`
whose text says why.
"""
import numbers

__all__ = ['NotANumber', 'real_number', 'shown']


class NotANumber(ValueError):
    """A value that is not a usable real number; the text says why (no key: the caller adds it)."""


def shown(value, limit=60):
    """A value for a message: its repr, cut to ``limit`` characters (a 400-digit literal)."""
    try:
        text = repr(value)
    except (Exception, SystemExit):   # noqa: BLE001 — a user's object whose __repr__ raises
        text = f"<{type(value).__name__} object>"
    return text if len(text) <= limit else f"{text[:limit]}… ({len(text)} characters)"


def real_number(value):
    """``value`` as a Python float if it is a real number (not text, not a bool), else
    NotANumber. Non-finite floats are returned as they are (the caller's range decides)."""
    # (numpy's bool is not a numbers.Real; Python's is, as an int)
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise NotANumber(f"expected a number, got {shown(value)} ({type(value).__name__})")
    try:
        return float(value)
    except OverflowError:
        raise NotANumber(f"{shown(value)} is beyond the float range (±1.8e308)") from None
    except (Exception, SystemExit) as exc:   # noqa: BLE001 — a Real whose __float__ raises
        raise NotANumber(f"{shown(value)} cannot be read as a number: {shown(exc)}") from None
