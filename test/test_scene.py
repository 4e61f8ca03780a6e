"""Scene files: every shipped scene loads; bad files and bad values give clear errors."""
import math

import pytest

from cvt_ros.parameters import SPECS, ParameterError, validate
from cvt_ros.physics.linkage import GrashofError
from cvt_ros.scene import (
    SceneError,
    available_scenes,
    key_applies,
    load_scene,
    params_file_problem,
    parse_override,
    read_scene,
    resolve,
)

REQUIRED = {'paper', 'conveyor', 'mixer', 'stiff_shaft', 'massless_clutch', 'rigid_shaft',
            'neutral_crank', 'near_grashof', 'grazing'}


def write(tmp_path, text, name='scene.yaml'):
    p = tmp_path / name
    p.write_text(text)
    return p


def test_every_shipped_scene_loads_and_uses_only_known_keys():
    assert REQUIRED <= set(available_scenes())
    for name in available_scenes():
        raw = read_scene(name)
        assert set(raw) <= set(SPECS)
        values = load_scene(name)
        assert set(values) == set(SPECS)


def test_paper_scene_has_the_values_of_physics_md():
    v = load_scene('paper')
    assert (v['linkage.rocker_length'], v['linkage.coupler_length'],
            v['linkage.pivot_distance']) == (0.10, 0.20, 0.20)
    assert (v['inertia.motor'], v['inertia.rocker'], v['inertia.clutch_driven'],
            v['inertia.output']) == (0.05, 0.002, 0.001, 0.5)
    assert v['shaft.stiffness'] == 500.0 and v['load.torque'] == 5.0
    assert v['motor.model'] == 'induction'


def test_rigid_scene_reads_yaml_infinity():
    assert math.isinf(load_scene('rigid_shaft')['shaft.stiffness'])


def test_flat_dotted_keys_equal_nested_keys(tmp_path):
    nested = write(tmp_path, "cvt_sim:\n  ros__parameters:\n    load:\n      torque: 7.5\n",
                   'a.yaml')
    flat = write(tmp_path, "cvt_sim:\n  ros__parameters:\n    load.torque: 7.5\n", 'b.yaml')
    assert load_scene(nested) == load_scene(flat)
    wildcard = write(tmp_path, "/**:\n  ros__parameters:\n    load.torque: 1e-3\n", 'c.yaml')
    assert load_scene(wildcard)['load.torque'] == 1e-3


def test_unknown_key_names_the_closest_and_the_valid_ones(tmp_path):
    p = write(tmp_path, "cvt_sim:\n  ros__parameters:\n    linkage:\n      crank_lenght: 0.03\n")
    with pytest.raises(SceneError) as err:
        load_scene(p)
    msg = str(err.value)
    assert 'linkage.crank_lenght' in msg and 'did you mean linkage.crank_length' in msg
    assert 'cvt-sim params' in msg and str(p) in msg
    far = write(tmp_path, "cvt_sim:\n  ros__parameters:\n    zzz: 1\n", 'far.yaml')
    with pytest.raises(SceneError, match='valid: clutch.release, .*inertia.output'):
        load_scene(far)


@pytest.mark.parametrize('body, fragment', [
    ("cvt_sim:\n  ros__parameters:\n    inertia:\n      output: -1.0\n", 'inertia.output'),
    ("cvt_sim:\n  ros__parameters:\n    inertia:\n      motor: fast\n", 'expected a number'),
    ("cvt_sim:\n  ros__parameters:\n    motor:\n      model: diesel\n", "is not one of"),
    ("cvt_sim:\n  ros__parameters:\n    shaft:\n      stiffness: .nan\n", 'not a finite'),
    ("cvt_sim:\n  ros__parameters:\n    linkage:\n      crank_length: 0.12\n", 'Grashof'),
    ("other_node:\n  ros__parameters:\n    load.torque: 1.0\n", "top key must be 'cvt_sim:'"),
    ("cvt_sim:\n  load.torque: 1.0\n", 'ros__parameters'),
    ("cvt_sim: [1, 2\n", 'not valid YAML'),
    ("", 'expected a map'),
])
def test_bad_scene_files_give_clear_errors(tmp_path, body, fragment):
    with pytest.raises(SceneError, match=fragment.replace('(', r'\(')):
        load_scene(write(tmp_path, body))


def test_missing_scene_lists_the_available_ones():
    with pytest.raises(SceneError, match='paper'):
        resolve('no_such_scene')


def test_overrides_parse_as_yaml_values():
    assert parse_override('shaft.stiffness=.inf') == ('shaft.stiffness', math.inf)
    assert parse_override('solver.rtol=1e-9') == ('solver.rtol', 1e-9)
    assert parse_override('motor.model=constant_torque') == ('motor.model', 'constant_torque')
    with pytest.raises(SceneError):
        parse_override('load.torque')


def test_validate_refuses_with_value_and_limit():
    with pytest.raises(GrashofError) as err:
        validate({'linkage.crank_length': 0.1})
    assert err.value.value == 0.1 and err.value.limit == pytest.approx(0.1)
    with pytest.raises(ParameterError, match=r'1.5 is outside \[0.0001, 1\]'):
        validate({'motor.breakdown_slip': 1.5})
    with pytest.raises(ParameterError, match='J2 > 0'):
        validate({'model.formulation': 'paper', 'inertia.rocker': 0.0})


def test_every_number_has_finite_physical_bounds_that_the_default_respects():
    for name, spec in SPECS.items():
        if spec.choices or isinstance(spec.default, str):
            continue
        assert math.isfinite(spec.low), name
        assert math.isfinite(spec.high) or spec.high_name, name
        assert spec.check(spec.default) == spec.default, name
        for outside in (spec.low - 1.0, spec.high * 10.0 + 1.0):
            if math.isfinite(outside) and not spec.contains(outside):
                with pytest.raises(ParameterError, match=name.replace('.', r'\.')):
                    spec.check(outside)


@pytest.mark.parametrize('name, value, message', [
    ('load.torque', 10 ** 400, r'beyond any float; accepted: \[-100000, 100000\]'),
    ('load.torque', 1e300, r'1e\+300 N\*m is outside \[-100000, 100000\]'),
    ('inertia.output', 5e-324, r'outside \[1e-06, 10000\]'),
    ('inertia.clutch_driven', 1e-12, r'outside 0 or \[1e-09, 1000\]'),
    ('inertia.motor', float('nan'), 'not a finite number'),
    ('shaft.stiffness', -float('inf'), 'not a finite number'),
    ('steps_per_command', 10 ** 30, r'outside \[0, 1e\+09\]'),
    ('steps_per_command', 2.5, 'whole number'),
    ('joint_prefix', 'x' * 300, 'at most 256 characters'),
    ('load.torque', [1] * 100, r'expected a number .*\(300 characters\)'),
])
def test_out_of_range_values_are_refused_with_value_and_limit(name, value, message):
    with pytest.raises(ParameterError, match=message):
        validate({name: value})


def test_degenerate_values_that_mean_something_stay_accepted():
    values = validate({'inertia.clutch_driven': 0.0, 'inertia.rocker': 0.0,
                       'shaft.stiffness': math.inf, 'linkage.crank_length': 0.0})
    assert values['inertia.clutch_driven'] == 0.0 and math.isinf(values['shaft.stiffness'])


def test_grashof_bound_is_exact_for_the_shipped_geometry():
    with pytest.raises(GrashofError, match=r'\[0, 0\.1\) m: the crank must be shorter than the '
                                           r'Grashof bound'):
        validate({'linkage.crank_length': 0.1})
    assert validate({'linkage.crank_length': 0.09999999999999999})


@pytest.mark.parametrize('content, fragment', [
    (b'cvt_sim:\n  ros__parameters:\n    load.torque: \xff\xfe\n', r'not UTF-8 text \(byte 45'),
    (b'cvt_sim: ' + b'[' * 3000 + b']' * 3000 + b'\n', 'nested deeper than 32 levels'),
    (b'a: &a [1, 1, 1, 1, 1, 1, 1, 1, 1]\nb: &b [*a, *a, *a, *a, *a, *a, *a, *a, *a]\n'
     b'c: &c [*b, *b, *b, *b, *b, *b, *b, *b, *b]\ncvt_sim: [*c, *c, *c, *c, *c, *c, *c]\n',
     r'alias \*a is not allowed'),
    (bytes(range(256)) * 4, 'not UTF-8 text'),
    (b'\x00' * 10, 'not valid YAML'),
    (b'x' * (2 << 20), 'larger than an input file may be'),
])
def test_hostile_scene_files_are_one_clear_error(tmp_path, content, fragment):
    p = tmp_path / 'hostile.yaml'
    p.write_bytes(content)
    with pytest.raises(SceneError, match=fragment) as err:
        load_scene(p)
    assert str(p) in str(err.value) and len(str(err.value)) < 600


def test_paths_that_are_not_scene_files(tmp_path):
    with pytest.raises(SceneError, match='not found') as err:
        load_scene('x' * 300)
    assert len(str(err.value)) < 600
    with pytest.raises(SceneError, match='not a regular file'):
        load_scene(tmp_path)
    with pytest.raises(SceneError, match='not found'):
        load_scene('bad\x00name')


def test_an_override_error_names_the_override_not_the_file():
    with pytest.raises(SceneError) as err:
        load_scene('paper', {'linkage.crank_length': 0.2},
                   {'linkage.crank_length': '--set linkage.crank_length=0.2'})
    assert str(err.value).startswith('--set linkage.crank_length=0.2: ') and 'paper' not in \
        str(err.value)
    with pytest.raises(SceneError, match=r'^override lod\.torque: lod\.torque: unknown'):
        load_scene('paper', {'lod.torque': 1.0})
    assert parse_override('load.torque=[&a 1, *a]')[1] == '[&a 1, *a]'   # alias: stays text


def test_a_ros2_param_dump_is_a_scene(tmp_path):
    """`ros2 param dump /cvt_sim` holds rclpy's own parameters too: the offline loader takes the
    dump as a scene and passes over them, as the node does."""
    dump = write(tmp_path, "/cvt_sim:\n  ros__parameters:\n    use_sim_time: false\n"
                           "    start_type_description_service: true\n"
                           "    qos_overrides:\n      /clock:\n        publisher:\n"
                           "          depth: 1\n    load:\n      torque: 7.0\n", 'dump.yaml')
    assert load_scene(dump)['load.torque'] == 7.0


@pytest.mark.parametrize('key, node, applies', [
    ('cvt_sim', '/cvt_sim', True), ('/cvt_sim', '/cvt_sim', True),
    ('cvt_sim', '/line1/cvt_sim', False), ('/**/cvt_sim', '/cvt_sim', True),
    ('/**/cvt_sim', '/line1/a/cvt_sim', True), ('/**/cvt_sim', '/line1/other', False),
    ('/**', '/line1/other', True), ('/*/cvt_sim', '/line1/cvt_sim', True),
    ('/*/cvt_sim', '/cvt_sim', False), ('/line1/cvt_sim', '/line2/cvt_sim', False)])
def test_params_file_keys_apply_as_ros_matches_them(key, node, applies):
    assert key_applies(key, node) is applies


def test_shipped_scenes_apply_to_the_node_in_any_namespace():
    for name in available_scenes():
        for node in ('/cvt_sim', '/line1/cvt_sim'):
            assert params_file_problem(resolve(name), node) is None, name
    assert 'no top key applies to this node, /line1/conveyor' in params_file_problem(
        resolve('conveyor'), '/line1/conveyor')
