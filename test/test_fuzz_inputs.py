"""Bad input never crashes, hangs or lies (issue 14): ``cvt-sim run`` fuzzed over parameter values,
command-line arguments and scene-file bytes.

Every case must end with exit code 0, 1 or 2, never a traceback, within a time budget (generous:
a hang is a loop that never ends, not a slow machine), and never print a non-finite number with
exit code 0. Cases run in a worker process (fuzz_worker.py) so that a hang is a failed case.
Hypothesis draws the cases; the example counts keep this module around a minute on 2 cores
(CVT_FUZZ_EXAMPLES raises them for a longer campaign: BENCHMARKS.md has the figures).
"""
import math
import os

import pytest
from fuzz_strategies import mutate, number_texts
from fuzz_worker import Worker, scaled_budget
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from cvt_ros.parameters import PHYSICS_PARAMETERS
from cvt_ros.scene import resolve

EXAMPLES = int(os.environ.get('CVT_FUZZ_EXAMPLES', '60'))
BUDGET = scaled_budget(60.0)   # seconds per case
RUN = ['run', 'paper', '--duration', '0.05', '--sample-dt', '0.01', '--quiet']
FUZZ = settings(max_examples=EXAMPLES, deadline=None, derandomize=True, database=None,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])
NUMERIC = sorted(s.name for s in PHYSICS_PARAMETERS
                 if not s.choices and not isinstance(s.default, str))


CASES = {'tried': 0, 'exit 0': 0, 'exit 1': 0, 'exit 2': 0}


@pytest.fixture(scope='module')
def worker():
    w = Worker()
    yield w
    w.close()
    report = os.environ.get('CVT_FUZZ_REPORT')   # a campaign's figures (BENCHMARKS.md)
    if report:
        with open(report, 'a') as f:
            f.write(f"{CASES}\n")


def check(worker, argv):
    outcome = worker.run(argv, BUDGET)
    CASES['tried'] += 1
    CASES[f'exit {outcome.code}'] = CASES.get(f'exit {outcome.code}', 0) + 1
    problems = outcome.problems()
    assert not problems, f"cvt-sim {' '.join(argv)}:\n" + '\n'.join(problems)
    return outcome


@FUZZ
@given(name=st.sampled_from(NUMERIC), value=number_texts())
def test_any_parameter_value_is_a_result_or_one_clear_error(worker, name, value):
    outcome = check(worker, RUN + ['--set', f'{name}={value}'])
    if outcome.code == 2:
        assert name in outcome.stderr or '--set' in outcome.stderr, outcome.stderr


def _seconds(text):
    try:
        return float(text)
    except ValueError:
        return math.nan


@FUZZ
@given(duration=number_texts(), sample_dt=number_texts())
def test_any_duration_and_sample_interval(worker, duration, sample_dt):
    # a valid long run is no hang, just long (it has a progress bar): keep to what ends quickly
    assume(not 1.0 < _seconds(duration.replace('_', '')) <= 1e7)
    check(worker, ['run', 'paper', '--quiet', '--duration', duration, '--sample-dt', sample_dt])


@FUZZ
@given(data=st.data())
def test_mutated_scene_files(worker, tmp_path_factory, data):
    content = mutate(data.draw, resolve('conveyor').read_bytes())
    path = tmp_path_factory.mktemp('scene') / 'mutated.yaml'
    path.write_bytes(bytes(content))
    check(worker, ['run', str(path), '--duration', '0.05', '--sample-dt', '0.01', '--quiet'])


@settings(FUZZ, max_examples=max(8, EXAMPLES // 4))
@given(data=st.data())
def test_mutated_n_path_scene_files(worker, tmp_path_factory, data):
    """Issue 33's scenes: paths.count and its neighbours mutated, the run recorded (the
    N-path recording's writer) and the recording analysed."""
    content = mutate(data.draw, resolve('conveyor_4path').read_bytes())
    folder = tmp_path_factory.mktemp('scene')
    path = folder / 'mutated.yaml'
    path.write_bytes(bytes(content))
    outcome = check(worker, ['run', str(path), '--duration', '0.05', '--sample-dt', '0.01',
                             '--quiet', '--mcap', str(folder / 'run.mcap')])
    if outcome.code in (0, 1) and (folder / 'run.mcap').exists():
        check(worker, ['analyze', str(folder / 'run.mcap'), '--cycles', '0'])


@pytest.mark.parametrize('argv', [
    RUN + ['--set', 'load.torque=1' + '0' * 400],
    RUN + ['--set', 'inertia.output=5e-324'],
    RUN + ['--set', 'load.torque=1e300'],
    RUN + ['--set', 'inertia.motor=1e308'],
    RUN + ['--set', 'motor.model=constant_speed', '--set', 'motor.speed=0'],
    ['run', 'paper', '--quiet', '--duration', '1e9'],
    ['run', 'paper', '--quiet', '--duration', '1', '--sample-dt', '5e-324'],
    ['run', 'x' * 300, '--duration', '1'],
    ['params', '--scene', 'x' * 300],
    ['run', 'paper', '--duration', 'nan'],
])
def test_the_reproductions_of_issue_14(worker, argv):
    """Each was a traceback, a hang or a NaN with exit 0; now a refusal (2) or a flagged
    answer (1: the ratio of a crank held at rest is undefined)."""
    assert check(worker, argv).code in (1, 2)
