"""The architecture as a contract: imports go only downward, no circles, no ROS in the core.

Layers, lowest first (docs/architecture.md draws them):

    physics < numbers, parameters, scene, yaml_file < solver < interface < recording < analysis
    < device < control, scenario < testing, sweep < design < bench, cli

A module may import its own layer and the layers below it, never one above; no two modules
import each other, directly or around a circle (imports inside functions count: a circle that
runs through a lazy import is still a circle); below ``device`` no module imports rclpy or a ROS
message package at import time, and physics and solver never do at all. Checked by reading every
module's source with ``ast``, not by importing it.
"""
import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parent.parent / 'cvt_ros'

LAYERS = [
    ('physics',),
    ('numbers', 'parameters', 'scene', 'yaml_file'),
    ('solver',),
    ('interface',),
    ('recording',),
    ('analysis',),
    ('device',),
    ('control', 'scenario'),
    ('testing', 'sweep'),
    ('design',),
    ('bench', 'cli', '__main__'),
]
RANK = {room: rank for rank, rooms in enumerate(LAYERS) for room in rooms}
# the package root (cvt_ros/__init__.py) is imported with every module: it is below them all
RANK['__init__'] = -1
DEVICE = RANK['device']
ROS_MODULES = ('rclpy', 'rcl_interfaces', 'std_msgs', 'sensor_msgs', 'std_srvs', 'rosgraph_msgs',
               'diagnostic_msgs', 'builtin_interfaces', 'visualization_msgs', 'geometry_msgs',
               'launch', 'launch_ros')
ROS_FREE_ENTIRELY = ('physics', 'solver')


def modules():
    """Dotted module name → source path, for every module of the package."""
    found = {}
    for path in sorted(PACKAGE.rglob('*.py')):
        parts = path.relative_to(PACKAGE.parent).with_suffix('').parts
        if parts[-1] == '__init__':
            parts = parts[:-1]
        found['.'.join(parts)] = path
    return found


def room(module):
    """The room (first component below cvt_ros) of a dotted module name."""
    parts = module.split('.')
    return parts[1] if len(parts) > 1 else '__init__'


def imports(module, path):
    """(imported module, line, at module level?) for every import statement of a module."""
    tree = ast.parse(path.read_text(), str(path))
    package = module if path.name == '__init__.py' else module.rpartition('.')[0]
    top_level = {id(node) for node in tree.body}
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                yield alias.name, node.lineno, id(node) in top_level
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split('.')
                base = base[:len(base) - node.level + 1]
                target = '.'.join(base + ([node.module] if node.module else []))
            else:
                target = node.module
            # `from . import interface` imports a module: name it
            names = [f"{target}.{a.name}" for a in node.names] if not node.module else [target]
            for name in names:
                yield name, node.lineno, id(node) in top_level


def own(name, known):
    """The package module an imported name refers to (longest known prefix), or None."""
    parts = name.split('.')
    while parts:
        candidate = '.'.join(parts)
        if candidate in known:
            return candidate
        parts.pop()
    return None


MODULES = modules()
EDGES = {m: [(own(n, MODULES), line, top) for n, line, top in imports(m, p)]
         for m, p in MODULES.items()}


def test_every_room_has_a_layer():
    rooms = {room(m) for m in MODULES} - {'__init__'}
    assert rooms <= set(RANK), sorted(rooms - set(RANK))


@pytest.mark.parametrize('module', sorted(MODULES))
def test_imports_go_only_downward(module):
    upward = [f"line {line}: {target} ({room(target)} is above {room(module)})"
              for target, line, _ in EDGES[module]
              if target and room(target) in RANK and RANK[room(target)] > RANK[room(module)]]
    assert not upward, f"{module} imports upward: {upward}"


@pytest.mark.parametrize('module', sorted(MODULES))
def test_no_ros_below_the_device(module):
    r = room(module)
    if RANK[r] >= DEVICE:
        return
    path = MODULES[module]
    ros = [(name, line, top) for name, line, top in imports(module, path)
           if name.split('.')[0] in ROS_MODULES]
    if r in ROS_FREE_ENTIRELY or r == '__init__':
        assert not ros, f"{module} imports ROS: {ros}"
    else:
        assert not [x for x in ros if x[2]], f"{module} imports ROS at import time: {ros}"


def test_no_circles():
    graph = {m: {t for t, _, _ in EDGES[m] if t and t != m} for m in MODULES}
    # a package __init__ re-exporting its own modules is not a circle with them
    for m in MODULES:
        graph[m] = {t for t in graph[m] if not (t.startswith(m + '.') and MODULES[m].name ==
                                                '__init__.py')}
    circles, state, stack = [], {}, []

    def visit(node):
        state[node] = 'open'
        stack.append(node)
        for nxt in sorted(graph[node]):
            if state.get(nxt) == 'open':
                circles.append(stack[stack.index(nxt):] + [nxt])
            elif nxt not in state:
                visit(nxt)
        stack.pop()
        state[node] = 'done'

    for m in sorted(graph):
        if m not in state:
            visit(m)
    assert not circles, '\n'.join(' → '.join(c) for c in circles)


def top_level_names(path):
    """Names a module binds at its top level (definitions, assignments, imports; also inside
    top-level if/try blocks)."""
    names, body = set(), list(ast.parse(path.read_text(), str(path)).body)
    while body:
        node = body.pop()
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            names.add(node.name)
        elif isinstance(node, (ast.Assign, ast.AnnAssign, ast.AugAssign)):
            targets = node.targets if isinstance(node, ast.Assign) else [node.target]
            names.update(n.id for t in targets for n in ast.walk(t) if isinstance(n, ast.Name))
        elif isinstance(node, (ast.Import, ast.ImportFrom)):
            names.update((a.asname or a.name).split('.')[0] for a in node.names)
        elif isinstance(node, (ast.If, ast.Try)):
            body += node.body + node.orelse + getattr(node, 'finalbody', [])
            body += [n for h in getattr(node, 'handlers', []) for n in h.body]
    return names


@pytest.mark.parametrize('module', sorted(MODULES))
def test_every_import_of_the_package_resolves(module):
    """`from .x import y` names a module of the package and something it defines, lazy imports
    too (a command's `--plot` imports its module only when asked: a module moved to another
    room once left two of them pointing at nothing)."""
    path = MODULES[module]
    package = module if path.name == '__init__.py' else module.rpartition('.')[0]
    broken = []
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if not isinstance(node, ast.ImportFrom):
            continue
        if node.level:
            base = package.split('.')
            target = '.'.join(base[:len(base) - node.level + 1] + ([node.module] if node.module
                                                                   else []))
        else:
            target = node.module
        if target.split('.')[0] != 'cvt_ros':
            continue
        if target not in MODULES:
            broken.append(f"line {node.lineno}: no module {target}")
            continue
        defined = top_level_names(MODULES[target])
        broken += [f"line {node.lineno}: {target} has no {a.name}" for a in node.names
                   if a.name != '*' and a.name not in defined
                   and f"{target}.{a.name}" not in MODULES]
    assert not broken, f"{module}: {broken}"
