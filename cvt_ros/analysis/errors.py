"""Typed errors of :mod:`cvt_ros.analysis` (the library raises, the command prints)."""

from __future__ import annotations

__all__ = ['AnalysisError']


class AnalysisError(Exception):
    """Nothing analysable in the input (not a recording of this node, unreadable, no samples)."""
