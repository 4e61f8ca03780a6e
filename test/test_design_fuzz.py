"""Bad input to the design tools never crashes, hangs or lies (issue 36): ``cvt-sim identify``,
``identify --grid``, ``tune`` and ``fmu`` fuzzed over their settings, as test_fuzz_inputs.py does
for ``cvt-sim run``: every case ends with exit code 0, 1 or 2 and one error line, never a
traceback, within a time budget; a refusal names the option. Cases run in a worker process
(fuzz_worker.py). A valid grid ends at an --out that cannot be written (no cluster starts);
CVT_FUZZ_EXAMPLES raises the example counts for a longer campaign.
"""
import os

import pytest
from fuzz_worker import Worker, scaled_budget
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from test_fuzz_inputs import number_texts

EXAMPLES = max(1, int(os.environ.get('CVT_FUZZ_EXAMPLES', '60')) // 5)
BUDGET = scaled_budget(120.0)
FUZZ = settings(max_examples=EXAMPLES, deadline=None, derandomize=True, database=None,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.function_scoped_fixture])
QUICK = ['--no-sweep', '--sample-dt', '0.004', '--quiet']
SETTINGS = ('step_time', 'settle_time', 'crank_step', 'load_step', 'max_frequency',
            'min_frequency', 'points', 'sample_dt', 'linkage.', 'load.', 'motor.')
OPTIONS = ['--crank-step', '--load-step', '--settle-time', '--step-time', '--max-frequency',
           '--min-frequency', '--points', '--sample-dt']


@pytest.fixture(scope='module')
def worker():
    w = Worker()
    yield w
    w.close()


def check(worker, argv):
    outcome = worker.run(argv, BUDGET)
    problems = outcome.problems()
    assert not problems, f"cvt-sim {' '.join(argv)}:\n" + '\n'.join(problems)
    return outcome


@FUZZ
@given(option=st.sampled_from(OPTIONS), value=number_texts())
def test_any_identify_setting_is_a_model_or_one_clear_error(worker, option, value):
    argv = ['identify', 'conveyor'] + [a for a in QUICK if not (option == '--sample-dt'
                                                                and a in ('--sample-dt', '0.004'))]
    outcome = check(worker, argv + [option, value])
    if outcome.code == 2:   # the option, or the setting that would make it work, named
        name = option.lstrip('-').replace('-', '_')
        assert any(word in outcome.stderr for word in (option, name) + SETTINGS), outcome.stderr


grid_values = st.one_of(
    number_texts(),
    st.lists(number_texts(), min_size=1, max_size=4).map(','.join),
    st.tuples(number_texts(), number_texts(), number_texts()).map(':'.join),
    st.text(max_size=30))


@FUZZ
@given(name=st.sampled_from(['linkage.crank_length', 'load.torque', 'motor.model', 'nope',
                             'inertia.output', '']), values=grid_values)
def test_any_grid_is_refused_or_reaches_its_output_check(worker, name, values, tmp_path):
    outcome = check(worker, ['identify', 'conveyor', '--grid', f'{name}={values}', '--out',
                             str(tmp_path / 'missing' / 'out')] + QUICK)
    assert outcome.code == 2 and ('--grid' in outcome.stderr or '--out' in outcome.stderr), \
        outcome.stderr


@FUZZ
@given(step=number_texts(), stop=number_texts())
def test_any_fmu_step_is_an_fmu_or_one_clear_error(worker, step, stop, tmp_path):
    out = tmp_path / 'x.fmu'
    outcome = check(worker, ['fmu', 'paper', '--out', str(out), '--overwrite', '--step', step,
                             '--stop-time', stop])
    assert (outcome.code == 0) == out.is_file()


@pytest.mark.parametrize('argv, words', [
    (['identify', 'conveyor', '--set', 'linkage.crank_length=0'] + QUICK, 'neutral crank'),
    (['identify', 'conveyor', '--set', 'motor.breakdown_torque=1'] + QUICK, 'stalls'),
    (['identify', 'conveyor', '--max-frequency', '20', '--quiet'], 'max_frequency'),
    (['identify', 'conveyor', '--grid', 'load.torque=1:2:200000', '--out', '/tmp'], '--grid'),
    (['tune', 'conveyor', '--tau-c', '0.001'] + QUICK[1:], 'tau_c'),
    (['fmu', 'conveyor', '--out', '/nonexistent/x.fmu'], '--out'),
])
def test_the_refusals_name_the_setting(worker, argv, words):
    outcome = check(worker, argv)
    assert outcome.code == 2 and words in outcome.stderr, outcome.stderr
