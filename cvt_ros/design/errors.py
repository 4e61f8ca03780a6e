"""The design tools' input error (a class of its own, so every module of the room can raise it)."""


class DesignError(ValueError):
    """A design question that has no answer for these settings (no steady state at the operating
    point, sweep frequencies the cycle mean cannot resolve, a grid beyond its time budget, an
    output that cannot be written); the message names the setting, its value and the limit."""
