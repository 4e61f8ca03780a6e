"""Bad input on the controller kit never crashes, hangs, lies or touches a user's file (issue 34):
``cvt-sim scenario run`` fuzzed over scenario files (mutated shipped ones and generated ones:
every key, schedules of every kind, profiles that are FIFOs, devices, folders, broken CSVs),
output targets (the scenario itself, a user's file, a folder, a full disk, an unwritable folder,
one file for two outputs, a suffix no plot has) and hostile controllers (answers that are text,
bools, huge integers, objects whose ``__float__`` raises; controllers and factories that raise).

Every case runs in a worker process (fuzz_worker.py) under a time budget and must end with exit
0, 1 or 2 and no traceback; exit 0 only with a run that completed and metrics to show; no file
that was in the folder before changes unless the command named it as an output and
``--overwrite`` was given, and an input never. The example counts keep this module well under
a minute on 2 cores; CVT_FUZZ_EXAMPLES raises them (BENCHMARKS.md "Bad input" has a campaign's
figures, CVT_FUZZ_REPORT collects them).
"""
import json
import os

import pytest
from fuzz_strategies import Tally, flow, fuzz_settings, leaf, mutate, snapshot, sometimes, touched
from fuzz_worker import Worker, scaled_budget
from hypothesis import given
from hypothesis import strategies as st

from cvt_ros.scenario.model import available_scenarios, resolve_scenario

BUDGET = scaled_budget(60.0)
FUZZ = fuzz_settings(20)
FILES = Tally('scenario files')
CONTROLLERS = Tally('controllers')
PROFILE = 't,load_torque\n0,8\n0.01,9\n0.02,7.5\n'


@pytest.fixture(scope='module')
def worker():
    w = Worker()
    yield w
    w.close()
    FILES.write()
    CONTROLLERS.write()


def _folder(tmp_path_factory):
    """A case's folder, as a user's: a scenario's neighbours that must survive every case."""
    folder = tmp_path_factory.mktemp('case')
    (folder / 'notes.json').write_text('{"mine": true}\n')
    (folder / 'plot.png').write_bytes(b'\x89PNG mine')
    (folder / 'good.csv').write_text(PROFILE)
    (folder / 'nan.csv').write_text('t,load_torque\n0,8\n0.01,nan\n')
    (folder / 'binary.csv').write_bytes(bytes(range(256)))
    (folder / 'sub').mkdir()
    os.mkfifo(folder / 'fifo.csv')
    return folder


def check(worker, tally, folder, argv, inputs, outputs, overwrite):
    """Run a case; the contract of the CLI, of the outputs and of the user's files."""
    before = snapshot(folder)
    outcome = worker.run([str(a) for a in argv], BUDGET)
    tally.outcome(outcome)
    problems = outcome.problems()
    after = snapshot(folder)
    named = {os.path.relpath(outputs[o], folder) for o in ('json', 'plot', 'mcap')
             if outputs.get(o)}
    replaceable = named - {os.path.relpath(p, folder) for p in inputs} if overwrite else set()
    changed = touched(before, after, replaceable)
    if changed:
        problems.append(f"user files touched: {changed}")
        tally['user files touched'] += 1
    if any(p.endswith('.part') or '.cvt-probe-' in p for p in after):
        problems.append(f"temporary file left: {sorted(after)}")
    if outcome.code == 0 and not outcome.hung:
        wrong = _wrong_output(outcome, outputs)
        if wrong:
            problems.append(wrong)
            tally['exit 0 with wrong output'] += 1
    if outcome.code == 2 and set(after) - set(before):
        problems.append(f"exit 2 but files written: {sorted(set(after) - set(before))}")
    assert not problems, f"cvt-sim {' '.join(map(str, argv))}:\n" + '\n'.join(problems)
    return outcome


def _wrong_output(outcome, outputs):
    """Why an exit-0 answer is not one ('' if it is)."""
    if 'completed' not in outcome.stdout or 'STOPPED' in outcome.stdout:
        return f"exit 0 without a completed run:\n{outcome.stdout}"
    path = outputs.get('json')
    if path:
        try:
            data = json.loads(open(path, encoding='utf-8').read())
        except (OSError, ValueError) as exc:
            return f"exit 0 but --json {path} is not JSON ({exc})"
        if not data.get('completed') or all(v is None for v in data['metrics'].values()):
            return f"exit 0 with a JSON of no result: {data.get('metrics')}"
    plot = outputs.get('plot')
    if plot and not (os.path.isfile(plot) and os.path.getsize(plot) > 100):
        return f"exit 0 but no plot at {plot}"
    return ''


def outputs(folder, scenario):
    """Targets for --json, --plot, --mcap: new names, a user's files, the scenario itself, the
    profile it reads, a folder, a full disk, an unwritable folder, a missing folder."""
    hostile = [folder / 'notes.json', scenario, folder / 'good.csv', folder / 'sub',
               '/dev/full', '/proc/cvt-fuzz.json', folder / 'no' / 'x.json', '']
    def one_of(usual, hostile):   # mostly usual targets: a case then reaches the writing
        return sometimes(0.25, st.sampled_from(hostile), st.sampled_from(usual))
    return st.fixed_dictionaries({
        'json': one_of([None, folder / 'out.json'], hostile),
        'plot': one_of([None, folder / 'out.png', folder / 'out.svg'],
                       [folder / 'out.svgx', folder / 'out', folder / 'plot.png', *hostile]),
        'mcap': one_of([None, None, folder / 'out.mcap'],
                       [folder / 'out.json', folder / 'notes.json', scenario]),
        'overwrite': st.booleans()})


def _argv(scenario, targets, extra=()):
    argv = ['scenario', 'run', scenario, '--quiet', *extra]
    for option in ('json', 'plot', 'mcap'):
        if targets[option] is not None:
            argv += [f'--{option}', targets[option]]
    if targets['overwrite']:
        argv.append('--overwrite')
    return argv


# ------------------------------------------------------------------------------ scenario files
@FUZZ
@given(data=st.data())
def test_mutated_scenario_files(worker, tmp_path_factory, data):
    folder = _folder(tmp_path_factory)
    name = data.draw(st.sampled_from(available_scenarios()))
    scenario = folder / 'mutated.yaml'
    scenario.write_bytes(mutate(data.draw, resolve_scenario(name).read_bytes()))
    targets = data.draw(outputs(folder, scenario))
    check(worker, FILES, folder, _argv(scenario, targets, ['--duration', '0.1']),
          [scenario], targets, targets['overwrite'])


def _times():
    return st.sampled_from(['0', '0.01', '0.02', '0.05', '0.049', '0.1', '1e-9', '0.0505'])


def _change(kind, at, **fields):
    """A schedule change as flow YAML: {at: T, KIND: {field: value, ...}} (a step: its value)."""
    body = fields['value'] if kind == 'step' else flow(list(fields.items()))
    return f"{{at: {at}, {kind}: {body}}}"


def _schedule(profiles):
    times = leaf(_times())
    step = st.builds(lambda at, v: _change('step', at, value=v), times,
                     leaf(st.sampled_from(['40', '70', '8', '-5', '1e4'])))
    ramp = st.builds(lambda at, to, d: _change('ramp', at, to=to, duration=d), times,
                     leaf(st.sampled_from(['60', '12'])), times)
    sine = st.builds(lambda at, a, f, d, p: _change('sine', at, amplitude=a, frequency=f,
                                                    duration=d, phase=p),
                     times, leaf(st.sampled_from(['1', '0', '1e3'])),
                     leaf(st.sampled_from(['5', '1e4', '0.5'])), times,
                     leaf(st.sampled_from(['0', '3.14'])))
    profile = st.builds(lambda at, f, c: _change('profile', at, file=f, column=c), times,
                        st.sampled_from(profiles), st.sampled_from(['load_torque', 'x', 'null']))
    changes = st.lists(st.one_of(step, ramp, sine, profile), max_size=4)
    return st.one_of(leaf(st.sampled_from(['55', '8'])),
                     st.builds(lambda i, c: f"{{initial: {i}, changes: [{', '.join(c)}]}}",
                               leaf(st.sampled_from(['55', '8', '0'])), changes))


def scenario_docs(folder):
    profiles = [str(folder / n) for n in ('good.csv', 'nan.csv', 'binary.csv', 'fifo.csv', 'sub',
                                          'missing.csv')] + ['/dev/zero', 'good.csv', '../x']
    keys = {
        'scene': leaf(st.sampled_from(['conveyor', 'paper', 'mixer', 'missing', '../x.yaml'])),
        'duration': leaf(sometimes(0.1, st.sampled_from(['1e-9', '86400', '1e5', '0.0505']),
                                   st.sampled_from(['0.05', '0.1', '0.002']))),
        'control_period': leaf(sometimes(0.1, st.just('1e-6'),
                                         st.sampled_from(['0.001', '0.0005', '0.01']))),
        'seed': leaf(sometimes(0.1, st.sampled_from([str(2 ** 63), str(2 ** 64)]),
                               st.sampled_from(['0', '7', str(2 ** 63 - 1)]))),
        'setpoint': _schedule(profiles), 'load': _schedule(profiles),
        'crank_limits': st.lists(st.tuples(st.sampled_from(['min', 'max', 'rate', 'x']),
                                           leaf(st.sampled_from(['0', '0.04', '0.09', '0.01']))),
                                 max_size=3).map(flow),
        'sensors': st.lists(st.tuples(
            st.sampled_from(['counts_per_turn', 'delay', 'decimation', 'noise']),
            leaf(st.sampled_from(['4096', '0.002', '2', '{position: 1e-4, velocity: 0.1}']))),
            max_size=3).map(flow),
        'actuator': st.lists(st.tuples(st.sampled_from(['deadband', 'backlash']),
                                       leaf(st.sampled_from(['0', '1e-4', '0.2']))),
                             max_size=2).map(flow),
        'controller': st.lists(st.tuples(
            st.sampled_from(['kp', 'ki', 'crank_min', 'crank_max', 'rate_limit',
                             'tracking_time', 'gain']),
            leaf(st.sampled_from(['0.002', '0', '0.05', '1e-9']))), max_size=3).map(flow),
        'overrides': st.lists(st.tuples(
            st.sampled_from(['load.torque', 'inertia.output', 'motor.model', 'shaft.stiffness',
                             'solver.method', 'nope']),
            leaf(st.sampled_from(['8', '0.5', 'constant_speed', '.inf', 'rk4']))),
            max_size=2).map(flow),
        'description': leaf(st.sampled_from(['"a test"', '[1]'])),
        'junk': st.just('1'),
    }
    required = ('scene', 'duration', 'setpoint')
    optional = [k for k in keys if k not in required]
    optional.remove('junk')
    return st.builds(
        lambda chosen, drop, junk, values: flow([(k, values[k]) for k in (*required, *chosen)
                                                 if k != drop] + junk),
        st.lists(st.sampled_from(optional), unique=True, max_size=6),
        sometimes(0.1, st.sampled_from(required), st.none()),
        sometimes(0.05, st.just([('junk', '1')]), st.just([])),
        st.fixed_dictionaries(keys))


@FUZZ
@given(data=st.data())
def test_generated_scenario_files(worker, tmp_path_factory, data):
    folder = _folder(tmp_path_factory)
    scenario = folder / 'generated.yaml'
    scenario.write_text(data.draw(scenario_docs(folder)))
    targets = data.draw(outputs(folder, scenario))
    inputs = [scenario] + [folder / n for n in ('good.csv', 'nan.csv', 'binary.csv')]
    check(worker, FILES, folder, _argv(scenario, targets), inputs, targets,
          targets['overwrite'])


# ------------------------------------------------------------------------------ controllers
KINDS = ['number', 'nan', 'inf', '-inf', 'text', 'bool', 'none', 'list', 'dict', 'complex',
         'bytes', 'numpy', 'fraction', 'decimal', 'float_raises', 'index_only', 'repr_raises',
         'raise', 'factory_raises', 'factory_returns']


def controller_specs():
    return st.fixed_dictionaries({
        'kind': st.sampled_from(KINDS),
        'value': st.one_of(st.integers(-10 ** 400, 10 ** 400), st.floats(), st.just('0.05'),
                           st.sampled_from([0.04, 0.0, -1.0, 1e308, 2 ** 1100, True, None,
                                            'float64', 'float32', 'int64', 'bool_'])),
        'error': st.sampled_from(['ValueError', 'ZeroDivisionError', 'SystemExit',
                                  'RecursionError', 'KeyError', 'TypeError', 'OverflowError']),
        'at': st.sampled_from([0, 1, 30])})


def _expected(spec):
    """The exit codes a controller of this kind may end with: 2 if its factory fails, 0 if its
    answer is None or a real, finite number (numbers.Real, not a bool), else 1 (it stops)."""
    import math
    import numbers

    from fuzz_controllers import answer
    if spec['kind'].startswith('factory'):
        return {2}
    try:
        value = answer(spec)
        if value is None:
            return {0}
        real = isinstance(value, numbers.Real) and not isinstance(value, bool) and \
            math.isfinite(float(value))
    except (Exception, SystemExit):   # noqa: BLE001 — what the controller raises stops it
        return {1}
    return {0} if real else {1}


@FUZZ
@given(spec=controller_specs())
def test_hostile_controllers(worker, tmp_path_factory, spec):
    folder = _folder(tmp_path_factory)
    scenario = folder / 'controlled.yaml'
    scenario.write_text(f"scene: conveyor\nduration: 0.05\nsetpoint: 55.0\n"
                        f"description: {json.dumps(json.dumps(spec))}\n")
    targets = {'json': folder / 'out.json', 'plot': None, 'mcap': None, 'overwrite': False}
    outcome = check(worker, CONTROLLERS, folder,
                    _argv(scenario, targets, ['--controller', 'fuzz_controllers:make']),
                    [scenario], targets, False)
    assert outcome.code in _expected(spec), (spec, outcome.stdout, outcome.stderr)
    if outcome.code == 1:   # the run stopped, said why and when, and kept what ran
        assert 'STOPPED: the controller' in outcome.stdout, outcome.stdout
        assert json.loads((folder / 'out.json').read_text())['completed'] is False
