"""Argument types shared by the ``cvt-sim`` commands: a bad value is one argparse error line."""
import argparse
import math


def _number(text):
    try:
        return float(text)
    except (ValueError, OverflowError):
        raise argparse.ArgumentTypeError(f"{text[:40]!r} is not a number") from None


def positive_float(text):
    """A finite number > 0."""
    value = _number(text)
    if not (value > 0.0 and math.isfinite(value)):
        raise argparse.ArgumentTypeError(f"{text[:40]!r} must be a positive finite number")
    return value


def non_negative_float(text):
    """A finite number ≥ 0."""
    value = _number(text)
    if not (value >= 0.0 and math.isfinite(value)):
        raise argparse.ArgumentTypeError(f"{text[:40]!r} must be a finite number ≥ 0")
    return value


def positive_seconds(largest, smallest=1e-9):
    """A time [s] in [smallest, largest]: 5e-324 s or 1e9 s is not a time anyone means."""
    def parse(text):
        value = positive_float(text)
        if not smallest <= value <= largest:
            raise argparse.ArgumentTypeError(
                f"{text[:40]!r} s is outside [{smallest:g}, {largest:g}] s")
        return value
    parse.__name__ = 'seconds'
    return parse


class Parser(argparse.ArgumentParser):
    """argparse with one error line (and where to look) instead of a usage block and a line."""

    def error(self, message):
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")
