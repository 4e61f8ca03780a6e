"""ParameterSpec (``cvt_ros.parameters``) → ROS parameter descriptor and value type.

A floating-point range is given wherever the spec has a bound; an infinite side becomes ±DBL_MAX
(rclpy's range check cannot hold inf). A parameter that may be +inf (the rigid shaft) has no
range here and is checked in the node's on-set callback, as are open bounds (> 0) and the gap
below a smallest positive value (denormal inertias): rclpy's ranges are closed.
"""
import math
import sys

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor

DBL_MAX = sys.float_info.max


def ros_value(spec, value):
    """A checked scene value as the Python type its ROS parameter is declared with."""
    kind = type(spec.default)
    if kind is bool:
        return bool(value)
    if kind is int:
        return int(value)
    if kind is float:
        return float(value)
    return str(value)


def describe(spec):
    """The ParameterDescriptor of a parameter: description, unit, range or choices."""
    d = ParameterDescriptor(name=spec.name, description=spec.description)
    kind = type(spec.default)
    if spec.choices:
        d.additional_constraints = f"one of: {', '.join(str(c) for c in spec.choices)}"
        if kind is int:
            values = sorted(spec.choices)
            steps = {b - a for a, b in zip(values, values[1:], strict=False)}
            d.integer_range = [IntegerRange(from_value=values[0], to_value=values[-1],
                                            step=steps.pop() if len(steps) == 1 else 0)]
    elif kind is str:
        d.additional_constraints = 'string'
    else:
        d.additional_constraints = f"unit: {spec.unit}; range: {spec.range_text()}"
        if kind is int:
            d.integer_range = [IntegerRange(
                from_value=int(spec.low) if math.isfinite(spec.low) else -2**63,
                to_value=int(spec.high) if math.isfinite(spec.high) else 2**63 - 1, step=1)]
        elif not spec.allow_inf and (math.isfinite(spec.low) or math.isfinite(spec.high)):
            d.floating_point_range = [FloatingPointRange(
                from_value=spec.low if math.isfinite(spec.low) else -DBL_MAX,
                to_value=spec.high if math.isfinite(spec.high) else DBL_MAX, step=0.0)]
    return d


__all__ = ['describe', 'ros_value']
