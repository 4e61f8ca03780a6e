"""Scene files: ROS 2 parameter files (``/**/cvt_sim: ros__parameters: {...}``) → validated values.

The same file configures the offline CLI and the node (``--ros-args --params-file``). Nested maps
flatten to dotted names (``linkage: {crank_length: 0.03}`` ≡ ``linkage.crank_length: 0.03``), as
the ROS 2 parameter-file parser does. The top key names the node as ROS matches it: ``cvt_sim``
is the node in the root namespace only, ``/**/cvt_sim`` the node in any namespace (the shipped
scenes), ``/**`` every node.
"""
import os
import re
import sys
from pathlib import Path

from . import parameters
from .physics.linkage import GrashofError
from .yaml_file import InputFileError, is_file, numbers_in, parse_value, read_yaml

NODE_NAME = 'cvt_sim'
SCENES_DIR = Path(__file__).resolve().parent.parent / 'config' / 'scenes'


# Parameters rclpy declares on every node (a `ros2 param dump` holds them): not the scene's; a
# scene file may carry them, and the offline loader and the node both pass over them.
ROS_OWN_PARAMETERS = ('use_sim_time', 'start_type_description_service')


def is_ros_own(name):
    """True for a parameter rclpy itself declares (use_sim_time, qos_overrides.*, ...)."""
    return name in ROS_OWN_PARAMETERS or name.startswith('qos_overrides.')


class SceneError(InputFileError):
    """A scene file that cannot be used; the message says which file, key and why."""


def config_dirs(kind):
    """Where names of shipped files of ``kind`` (scenes, scenarios, campaigns) are looked up:
    the source tree's config/KIND, then the installed share folder's."""
    dirs = [SCENES_DIR.parent / kind]
    # a ROS workspace (AMENT_PREFIX_PATH) or a plain pip install (data_files under sys.prefix)
    for prefix in os.environ.get('AMENT_PREFIX_PATH', '').split(os.pathsep) + [sys.prefix]:
        if prefix:
            dirs.append(Path(prefix) / 'share' / 'cvt_ros' / 'config' / kind)
    return [d for d in dirs if d.is_dir()]


def shipped_file(kind, name):
    """config/KIND/NAME.yaml of the first of :func:`config_dirs` that has it, or None."""
    for d in config_dirs(kind):
        candidate = d / f"{name}.yaml"
        if is_file(candidate):
            return candidate
    return None


def scene_dirs():
    """Where scene names are looked up: the source tree, then the installed share folder."""
    return config_dirs('scenes')


def available_scenes(n_paths=None):
    """The shipped scenes' names; ``n_paths``: only those of that many paths (``paths.count``:
    the one-path scenes are the paper's machine, conveyor_4path and mixer_3path are not)."""
    names = set()
    for d in scene_dirs():
        names.update(p.stem for p in d.glob('*.yaml'))
    if n_paths is not None:
        names = {n for n in names if read_scene(n).get('paths.count', 1) == n_paths}
    return sorted(names)


def resolve(scene):
    """A path, or a scene name such as ``paper`` (config/scenes/paper.yaml)."""
    if is_file(scene):
        return Path(scene)
    name = os.fspath(scene)
    if '\x00' not in name and len(name) < 4096 and os.path.exists(name):
        raise SceneError(f"{name}: not a regular file (a scene is a .yaml file)")
    if '/' not in name and os.sep not in name:
        found = shipped_file('scenes', name)
        if found is not None:
            return found
    shown = name if len(name) <= 120 else f"{name[:120]}… ({len(name)} characters)"
    raise SceneError(f"scene {shown!r} not found: not a file, and not one of "
                     f"{', '.join(available_scenes()) or '(no scenes installed)'}")


def _flatten(tree, prefix=''):
    flat = {}
    for key, value in tree.items():
        name = f"{prefix}{key}"
        if isinstance(value, dict):
            flat.update(_flatten(value, name + '.'))
        else:
            flat[name] = value
    return flat


def _yaml_number(value):
    # YAML 1.1 (PyYAML) reads '1e-3' (no dot) as a string; ROS's parser reads it as a double.
    return numbers_in(value) if isinstance(value, str) else value


def key_applies(key, fully_qualified_name):
    """Whether a params file's top key applies to the node ``fully_qualified_name`` (e.g.
    ``/line1/cvt_sim``), by rcl's rules: a key without a leading '/' is absolute, a '*' token
    stands for one name, '**' for any number of them."""
    tokens = str(key).strip('/').split('/')
    pattern = ''.join('(/[^/]+)*' if tok == '**' else '/[^/]+' if tok == '*' else
                      '/' + re.escape(tok) for tok in tokens)
    return re.fullmatch(pattern, fully_qualified_name) is not None


def params_file_problem(path, fully_qualified_name):
    """Why ROS would give the node nothing from the params file ``path`` (no top key applies to
    it, so the whole file is skipped without a word), or None."""
    doc = read_yaml(Path(path), SceneError)
    keys = list(doc) if isinstance(doc, dict) else []
    if any(key_applies(k, fully_qualified_name) for k in keys):
        return None
    return (f"{path}: no top key applies to this node, {fully_qualified_name} (the file's keys: "
            f"{', '.join(map(str, keys)) or 'none'}), so ROS would skip the whole file; name the "
            f"node in any namespace with '/**/{fully_qualified_name.rpartition('/')[2]}:' (as "
            f"the shipped scenes do) or write '{fully_qualified_name}:'")


def read_scene(path):
    """The raw parameter map of a scene file (dotted names), without validation."""
    path = resolve(path)
    doc = read_yaml(path, SceneError)
    if not isinstance(doc, dict) or not doc:
        raise SceneError(f"{path}: expected a map with top key '{NODE_NAME}:' (or '/**:')")
    keys = [k for k in doc if k in (NODE_NAME, f'/{NODE_NAME}', '/**') or
            str(k).endswith(f'/{NODE_NAME}')]
    if not keys:
        raise SceneError(f"{path}: top key must be '{NODE_NAME}:' (the node name), found "
                         f"{list(doc)}")
    flat = {}
    for k in keys:
        body = doc[k]
        if not isinstance(body, dict) or 'ros__parameters' not in body:
            raise SceneError(f"{path}: '{k}:' must contain 'ros__parameters:'")
        params = body['ros__parameters'] or {}
        if not isinstance(params, dict):
            raise SceneError(f"{path}: 'ros__parameters' must be a map of parameters")
        flat.update({str(name): _yaml_number(v) for name, v in _flatten(params).items()
                     if not is_ros_own(str(name))})
    return flat


def load_scene(path, overrides=None, origins=None):
    """Validated parameter values of a scene, with ``overrides`` (dotted name → value) applied.

    An error names where the bad value came from: the scene file, or the override as the user
    gave it (``origins``: name → e.g. ``'--set load.torque=1e300'``; default ``'override NAME'``).
    """
    raw = read_scene(path) if path is not None else {}
    where = f"{resolve(path)}: " if path is not None else ''
    overrides = dict(overrides or {})
    if overrides:
        _validated(raw, where)   # the file on its own first: its own errors name the file
    origins = origins or {}
    try:
        return parameters.validate(dict(raw, **overrides))
    except (parameters.ParameterError, GrashofError) as exc:
        blamed = [n for n in overrides if n == getattr(exc, 'name', None)] or \
            [n for n in overrides if isinstance(exc, GrashofError) and n.startswith('linkage.')]
        if blamed:
            where = ', '.join(origins.get(n, f"override {n}") for n in blamed) + ': '
        raise SceneError(f"{where}{exc}") from None


def _validated(raw, where):
    try:
        return parameters.validate(raw)
    except (parameters.ParameterError, GrashofError) as exc:
        raise SceneError(f"{where}{exc}") from None


def parse_override(text):
    """``key=value`` from the command line; the value is read as YAML (numbers, .inf, strings)."""
    if '=' not in text:
        raise SceneError(f"--set expects key=value, got {text!r}")
    key, _, raw = text.partition('=')
    return key.strip(), _yaml_number(parse_value(raw))
