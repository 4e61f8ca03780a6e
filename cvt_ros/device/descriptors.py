"""The node's parameters as ROS sees them: the values it starts with, the descriptor of each
(``ParameterSpec`` of ``cvt_ros.parameters`` → ``rcl_interfaces/ParameterDescriptor``), what
``ros2 param set`` / ``ros2 param load`` send turned into the declared type, and the table of
docs/node.md (``cvt-sim params --node --markdown``). No rclpy here: the node (``node.py``) wires
these into its parameter callbacks.

Ranges: a floating-point range is given where both bounds are finite; the crank length's upper
bound is the Grashof bound of the geometry the node has now (``node.py`` re-describes it when the
geometry changes). ROS ranges are closed: open bounds (``real_time_factor > 0``, ``a < bound``)
and the gap below a smallest positive value (denormal inertias) are checked by the node's on-set
callback, with the exact range in ``additional_constraints``. ``shaft.stiffness`` may be ``.inf``
and so has no range.
"""
import difflib
import math
import re

from rcl_interfaces.msg import FloatingPointRange, IntegerRange, ParameterDescriptor, ParameterType

from .. import parameters as params_mod
from ..parameters import ParameterError
from ..physics.linkage import GrashofError, grashof_bound
from ..scene import ROS_OWN_PARAMETERS, SceneError, is_ros_own, read_scene

DEFAULT_SCENE = 'conveyor'
# The node's solver when neither the scene nor -p names one, by the time_mode it starts in:
# realtime takes rk4, fixed sub-steps with events located inside the step, so every control period
# costs about the same (dopri5's adaptive steps make it vary); lockstep and fast have no deadline
# and take the offline default dopri5: error-controlled, the same answer as `cvt-sim run`.
REALTIME_SOLVER = 'rk4'
#: Why (``cvt-sim params --node``, docs/node.md): rk4 is exact on every shipped scene since
#: issue 32 (test_events.py::test_the_realtime_solver_is_right_on_every_shipped_scene).
REALTIME_SOLVER_WHY = (
    "realtime starts with solver.method rk4: fixed sub-steps (solver.fixed_step, refined until "
    "h·λ ≤ 0.5 for the fastest rate it integrates), so every control period costs about the same "
    "(BENCHMARKS.md, Cost per control period); the open clutch's output runs apart from the "
    "steps, exactly, as with dopri5, and every switch is located inside its step: on every "
    "shipped scene it makes dopri5's switches. lockstep and fast start with dopri5 "
    "(error-controlled, the answer of `cvt-sim run`). /diagnostics' key 'solver' says which runs "
    "and its 'possible_missed_events' whether the self-check suspects a missed clutch event")
# parameters rclpy declares itself: allowed in params files and -p (scene.ROS_OWN_PARAMETERS)
FOREIGN_PARAMETERS = ROS_OWN_PARAMETERS

# A number as Python's str() writes it (and so ``ros2 param dump`` → ``load``, ros2/rclpy#1672)
# that YAML 1.1 reads as a string: no dot (``2e-06``), or Python's ``inf``/``nan``.
_NUMBER = re.compile(r'[-+]?((\d+\.?\d*|\.\d+)([eE][-+]?\d+)?|inf|infinity|nan)', re.IGNORECASE)


def node_values(base_scene=DEFAULT_SCENE, overrides=None):
    """The validated values the node starts with: ``base_scene`` (name or path; None = the
    built-in defaults, as ``cvt-sim run``), then ``overrides`` (name → value: the params file and
    ``-p``); ``solver.method``, if neither sets it, by the time_mode it starts in
    (``start_solver``). An unknown name (a typo must not run the wrong experiment) or an invalid
    scene raises SceneError with the reason."""
    raw = {} if base_scene is None else read_scene(base_scene)
    for name, value in sorted((overrides or {}).items()):
        if name in params_mod.SPECS:
            raw[name] = value
        elif not is_ros_own(name):
            raise SceneError(f"unknown parameter {name}{closest_name(name)}; "
                             f"`cvt-sim params --node` lists them")
    raw.setdefault('solver.method', start_solver(raw.get('time_mode',
                                                         params_mod.SPECS['time_mode'].default)))
    try:
        values = params_mod.validate(raw)
        # the node's offsets are explicit (its double-array parameter: ROS cannot type an
        # empty one), the scene's default spelled out
        values['paths.phase_offsets'] = params_mod.phase_offsets(values)
        return values
    except (ParameterError, GrashofError) as exc:
        where = f" (base scene {base_scene})" if base_scene else ''
        raise SceneError(f"invalid scene parameters{where}: {exc}") from None


def start_solver(time_mode):
    """The node's solver.method when nothing names one: rk4 in realtime, else dopri5."""
    return REALTIME_SOLVER if time_mode == 'realtime' else params_mod.SPECS['solver.method'].default


def closest_name(name):
    """`` (did you mean load.torque?)`` for a name the node does not have, or ``''``."""
    close = difflib.get_close_matches(name, params_mod.SPECS, n=1)
    return f" (did you mean {close[0]}?)" if close else ''


def upper_bound(spec, values):
    """The upper bound that applies with ``values``: the crank length's is the Grashof bound of
    their geometry (exclusive), every other parameter's its own."""
    if spec.name == 'linkage.crank_length':
        return grashof_bound(values['linkage.rocker_length'], values['linkage.coupler_length'],
                             values['linkage.pivot_distance'])
    return spec.high


def range_text(spec, values):
    """The accepted values with ``values`` in force: ``[0, 0.1)``, ``(0, 1000]``, ``0 or ...``."""
    bound = upper_bound(spec, values)
    return spec.range_text(bound if spec.high_name else None)


def ros_value(spec, value):
    """A checked scene value as the Python type its ROS parameter is declared with."""
    kind = type(spec.default)
    if kind is bool:
        return bool(value)
    if kind is int:
        return int(value)
    if kind is float:
        return float(value)
    if kind is tuple:   # a double array (paths.phase_offsets)
        return [float(x) for x in value]
    return str(value)


def coerce(spec, value):
    """A value as ``ros2 param set`` / ``load`` send it, in the type ``spec`` is declared with
    where the meaning is plain: an integer for a double (``load.torque 10``), a number YAML 1.1
    read as text (``2e-06``, ``inf``: what ``ros2 param dump`` writes for such values), a whole
    double for an integer (``steps_per_command 10.0``). Anything else is returned as it is, for
    rclpy's type check and the node's range checks to refuse with the reason."""
    kind = type(spec.default)
    if kind is float:
        if isinstance(value, int) and not isinstance(value, bool):
            return float(value)
        if isinstance(value, str) and _NUMBER.fullmatch(value.strip()):
            return float(value)
    elif kind is int and isinstance(value, float) and value.is_integer():
        return int(value)
    return value


def describe(spec, values):
    """The ParameterDescriptor of a parameter: description, unit and range (or choices) as they
    apply with ``values`` (the Grashof bound of their geometry for the crank length)."""
    kind = type(spec.default)
    d = ParameterDescriptor(name=spec.name, description=spec.description, type=_TYPES[kind])
    if spec.choices:
        d.additional_constraints = f"one of: {', '.join(str(c) for c in spec.choices)}"
        if kind is int:
            choices = sorted(spec.choices)
            steps = {b - a for a, b in zip(choices, choices[1:], strict=False)}
            d.integer_range = [IntegerRange(from_value=choices[0], to_value=choices[-1],
                                            step=steps.pop() if len(steps) == 1 else 0)]
        return d
    if kind in (str, tuple):
        d.additional_constraints = spec.range_text()
        return d
    low, high = spec.low, upper_bound(spec, values)
    d.additional_constraints = f"unit: {spec.unit}; range: {range_text(spec, values)}"
    if spec.high_name:
        d.additional_constraints += f" ({spec.high_name} of the present geometry)"
    if not (math.isfinite(low) and math.isfinite(high)) or spec.allow_inf:
        return d   # ROS ranges cannot hold inf: the range is in additional_constraints
    if kind is int:
        d.integer_range = [IntegerRange(from_value=int(low), to_value=int(high), step=1)]
    else:
        d.floating_point_range = [FloatingPointRange(from_value=low, to_value=high, step=0.0)]
    return d


_TYPES = {bool: ParameterType.PARAMETER_BOOL, int: ParameterType.PARAMETER_INTEGER,
          float: ParameterType.PARAMETER_DOUBLE, str: ParameterType.PARAMETER_STRING,
          tuple: ParameterType.PARAMETER_DOUBLE_ARRAY}


def parameter_table(values):
    """docs/node.md's parameter table (Markdown) for ``values``: name, value, unit, accepted
    values (the Grashof bound of their geometry for the crank length), meaning."""
    rows = ['| parameter | default | unit | range / choices | meaning |',
            '|---|---|---|---|---|']
    for name, spec in params_mod.SPECS.items():
        if spec.choices:
            accepted = ' | '.join(_yaml_text(c) for c in spec.choices)
        elif isinstance(spec.default, (str, tuple)):
            accepted = spec.range_text()
        else:
            accepted = range_text(spec, values)
        cells = (f"`{name}`", _yaml_text(values[name]), spec.unit, accepted, spec.description)
        rows.append('| ' + ' | '.join(c.replace('|', '\\|') for c in cells) + ' |')
    return '\n'.join(rows) + '\n'


def _yaml_text(value):
    """A value as it is written in a params file: ``true``, ``''``, ``.inf``, ``1e-08``."""
    if isinstance(value, bool):
        return 'true' if value else 'false'
    if isinstance(value, str):
        return value or "''"
    if isinstance(value, float) and math.isinf(value):
        return '.inf' if value > 0 else '-.inf'
    if isinstance(value, tuple):
        return '[' + ', '.join(_yaml_text(float(x)) for x in value) + ']'
    return params_mod.number_text(value) if isinstance(value, float) else str(value)


__all__ = ['DEFAULT_SCENE', 'REALTIME_SOLVER', 'FOREIGN_PARAMETERS', 'node_values',
           'start_solver', 'closest_name', 'upper_bound', 'range_text', 'ros_value', 'coerce',
           'describe', 'parameter_table']
