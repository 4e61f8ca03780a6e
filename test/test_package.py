"""package.xml declares what the code imports (`rosdep install` then gives a working package).

Every third-party module imported anywhere in cvt_ros/ or launch/ maps to a rosdep key
(MODULE_KEYS); each key must be an exec_depend of package.xml, and each key rosdistro does not
define must be defined in the repository's rosdep.yaml (docs/architecture.md: how to add it as a
source).
"""
import ast
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parent.parent

# imported module → rosdep key (ROS packages are their own keys)
MODULE_KEYS = {
    'numpy': 'python3-numpy', 'scipy': 'python3-scipy', 'yaml': 'python3-yaml',
    'numba': 'python3-numba', 'matplotlib': 'python3-matplotlib', 'tqdm': 'python3-tqdm',
    'pytest': 'python3-pytest', 'psutil': 'python3-psutil',
    # mcap brings lz4 and zstandard (the reader's decompressors for other writers' files)
    'mcap': 'python3-mcap-pip', 'lz4': 'python3-mcap-pip', 'zstandard': 'python3-mcap-pip',
    'dask': 'python3-dask-distributed-pip', 'distributed': 'python3-dask-distributed-pip',
    'pyarrow': 'python3-pyarrow-pip',
    'sksundae': 'python3-scikit-sundae-pip',
    'control': 'python3-control-pip', 'pythonfmu': 'python3-pythonfmu-pip',
    'fmpy': 'python3-fmpy-pip',
}
ROS_PACKAGES = {'rclpy', 'rcl_interfaces', 'std_msgs', 'sensor_msgs', 'std_srvs', 'rosgraph_msgs',
                'diagnostic_msgs', 'geometry_msgs', 'visualization_msgs', 'builtin_interfaces',
                'ament_index_python', 'launch', 'launch_ros'}
# keys rosdistro's rosdep/python.yaml defines (checked against rosdistro master, 2026-11)
UPSTREAM_KEYS = {'python3-numpy', 'python3-scipy', 'python3-yaml', 'python3-numba',
                 'python3-matplotlib', 'python3-tqdm', 'python3-pytest', 'python3-psutil'}


def imported_modules():
    roots = set()
    files = list((ROOT / 'cvt_ros').rglob('*.py')) + list((ROOT / 'launch').glob('*.py'))
    for path in files:
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                roots |= {a.name.split('.')[0] for a in node.names}
            elif isinstance(node, ast.ImportFrom) and not node.level:
                roots.add(node.module.split('.')[0])
    return {r for r in roots if r not in sys.stdlib_module_names and r != 'cvt_ros'}


def declared():
    root = ET.parse(ROOT / 'package.xml').getroot()
    return {e.text.strip() for e in root if e.tag in ('exec_depend', 'depend')}


def test_every_import_has_a_rosdep_key_declared_in_package_xml():
    keys = {}
    for module in sorted(imported_modules()):
        assert module in MODULE_KEYS or module in ROS_PACKAGES, (
            f"cvt_ros imports {module!r}: add its rosdep key to MODULE_KEYS here, an "
            f"<exec_depend> to package.xml, and the key to rosdep.yaml if rosdistro has none")
        keys[module] = MODULE_KEYS.get(module, module)
    missing = sorted({k for k in keys.values() if k not in declared()})
    assert not missing, f"package.xml lacks <exec_depend> for {missing}"


def test_keys_rosdistro_lacks_are_defined_in_rosdep_yaml():
    own = yaml.safe_load((ROOT / 'rosdep.yaml').read_text())
    needed = {k for k in declared() if k.endswith('-pip')}
    assert needed <= set(own), sorted(needed - set(own))
    for key in needed:
        assert own[key]['debian']['pip']['packages'] and own[key]['ubuntu']['pip']['packages']
    unknown = {k for k in declared() if k.startswith('python3-')} - UPSTREAM_KEYS - set(own)
    assert not unknown, f"keys neither in rosdistro nor in rosdep.yaml: {sorted(unknown)}"
