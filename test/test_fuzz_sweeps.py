"""Bad input on campaigns never crashes, hangs or touches a user's file (issue 34): campaign files
(mutated shipped ones and generated ones) checked with ``cvt-sim sweep --dry-run``, and real
sweeps into output folders that already hold things — a user's campaign.yaml and summary.png,
junk or another campaign's results.parquet, an unreadable part, a file where the folder should
be, a forged ownership record — on a Dask cluster of this machine.

Every case runs in a worker process (fuzz_worker.py) under a time budget: exit 0, 1 or 2, no
traceback; a dry run writes nothing; no file that was in the folder before changes unless it is
the sweep's own output (its table, and campaign.yaml / summary.png with --overwrite). The
example counts keep this module around half a minute; CVT_FUZZ_EXAMPLES raises them, and
CVT_FUZZ_REPORT collects the counts (BENCHMARKS.md "Bad input").
"""
import textwrap

import pytest
from fuzz_strategies import Tally, flow, fuzz_settings, leaf, mutate, snapshot, sometimes, touched
from fuzz_worker import Worker, scaled_budget
from hypothesis import given
from hypothesis import strategies as st

from cvt_ros.sweep.campaign import resolve_campaign

BUDGET = scaled_budget(120.0)
FUZZ = fuzz_settings(20)
CAMPAIGNS = Tally('campaign files')
FOLDERS = Tally('sweep output folders')
SHIPPED = ('conveyor_ratio_map', 'conveyor_pi_gains', 'conveyor_shaft_stiffness')
TINY = """\
    name: tiny
    scene: conveyor
    duration: 0.1
    vary: {load.torque: [4.0, 8.0]}
    """


@pytest.fixture(scope='module')
def worker():
    w = Worker()
    yield w
    w.close()
    CAMPAIGNS.write()
    FOLDERS.write()


def check(worker, tally, folder, argv, may_change=()):
    before = snapshot(folder)
    outcome = worker.run([str(a) for a in argv], BUDGET)
    tally.outcome(outcome)
    problems = outcome.problems()
    changed = touched(before, snapshot(folder), may_change)
    if changed:
        tally['user files touched'] += 1
        problems.append(f"user files touched: {changed}")
    assert not problems, f"cvt-sim {' '.join(map(str, argv))}:\n" + '\n'.join(problems)
    return outcome


# ------------------------------------------------------------------------------ campaign files
@FUZZ
@given(data=st.data())
def test_mutated_campaign_files(worker, tmp_path_factory, data):
    folder = tmp_path_factory.mktemp('campaign')
    path = folder / 'mutated.yaml'
    path.write_bytes(mutate(data.draw, resolve_campaign(data.draw(st.sampled_from(SHIPPED)))
                            .read_bytes()))
    outcome = check(worker, CAMPAIGNS, folder, ['sweep', path, '--out', folder / 'out',
                                                '--dry-run'])
    assert outcome.code in (0, 2) and not (folder / 'out').exists()


def _value():
    return leaf(st.sampled_from(['0.03', '0.05', '8.0', '1e-3', '[0.01, 0.02]',
                                 '{range: [0.01, 0.05], num: 3}', '{values: [1, 2]}']))


def campaign_docs():
    names = st.sampled_from(['linkage.crank_length', 'load.torque', 'shaft.stiffness',
                             'controller.kp', 'controller.ki', 'solver.method', 'time_mode',
                             'nope', 'controller.x'])
    keys = {
        'name': leaf(st.sampled_from(['ok', 'n' * 300, '"a/b"'])),
        'scene': leaf(st.sampled_from(['conveyor', 'paper', 'missing'])),
        'scenario': leaf(st.sampled_from(['conveyor_setpoint_steps', 'conveyor_load_step'])),
        'duration': leaf(st.sampled_from(['0.2', '2', '86400', '1e-9'])),
        'sample_dt': leaf(st.sampled_from(['1e-3', '0.01', '0.5'])),
        'window': leaf(st.sampled_from(['steady', '{start: 0.1}', '{start: 100}', '{start: 1}'])),
        'vary': st.lists(st.tuples(names, _value()), max_size=3).map(flow),
        'cases': st.lists(st.lists(st.tuples(names, leaf(st.sampled_from(['0.03', '8']))),
                                   max_size=2).map(flow), max_size=3).map(
            lambda c: f"[{', '.join(c)}]"),
        'sampling': leaf(st.sampled_from(['grid', 'random', 'latin_hypercube', 'sobol'])),
        'samples': leaf(st.sampled_from(['4', '0', str(10 ** 7)])),
        'seed': leaf(st.sampled_from(['0', str(2 ** 64)])),
        'metrics': leaf(st.sampled_from(['[mean_ratio]', '[iae, overshoot]', '[]', '[x]'])),
        'time_budget': leaf(st.sampled_from(['10', '0', '1e9'])),
        'record': leaf(st.sampled_from(['none', 'csv', 'mcap', 'wav'])),
        'controller': leaf(st.sampled_from(['fuzz_controllers:make', 'nope:x', 'x'])),
        'overrides': st.lists(st.tuples(names, leaf(st.sampled_from(['0.04', 'rk4']))),
                              max_size=2).map(flow),
        'summary': leaf(st.sampled_from(['{x: load.torque}', '{metrics: [iae]}', '{z: 1}'])),
    }
    base = st.sampled_from(['scene', 'scenario'])
    return st.builds(
        lambda kind, chosen, values: flow([(kind, values[kind])] + [
            (k, values[k]) for k in chosen if k not in ('scene', 'scenario')]),
        base, st.lists(st.sampled_from(list(keys)), unique=True, min_size=1, max_size=7),
        st.fixed_dictionaries(keys))


@FUZZ
@given(doc=campaign_docs())
def test_generated_campaign_files(worker, tmp_path_factory, doc):
    folder = tmp_path_factory.mktemp('campaign')
    path = folder / 'generated.yaml'
    path.write_text(doc)
    outcome = check(worker, CAMPAIGNS, folder, ['sweep', path, '--out', folder / 'out',
                                                '--dry-run'])
    assert outcome.code in (0, 2) and not (folder / 'out').exists()


# ------------------------------------------------------------------------------ output folders
@pytest.fixture(scope='module')
def cluster():
    """A Dask cluster of this machine (one worker process) that every case's sweep joins."""
    from cvt_ros.sweep.cluster import open_cluster
    with open_cluster(workers=1, dashboard=None) as handle:
        yield handle.address


@pytest.fixture(scope='module')
def finished(worker, cluster, tmp_path_factory):
    """The tiny campaign, and a folder where it ran to the end (its table, for a rerun)."""
    folder = tmp_path_factory.mktemp('finished')
    campaign = folder / 'tiny.yaml'
    campaign.write_text(textwrap.dedent(TINY))
    outcome = worker.run(['sweep', str(campaign), '--out', str(folder / 'out'), '--scheduler',
                          cluster, '--quiet'], BUDGET)
    assert outcome.code == 0, outcome.stderr + outcome.traceback
    other = folder / 'other.yaml'
    other.write_text(textwrap.dedent(TINY).replace('[4.0, 8.0]', '[5.0]'))
    outcome = worker.run(['sweep', str(other), '--out', str(folder / 'other'), '--scheduler',
                          cluster, '--quiet'], BUDGET)
    assert outcome.code == 0, outcome.stderr + outcome.traceback
    return campaign, folder


CONTENT = {
    'campaign.yaml': [b'# my own notes\n', None],        # None: the campaign's own text
    'summary.png': [b'\x89PNG my plot'],
    'results.parquet': [b'PAR1 junk', 'own', 'other'],   # 'own'/'other': a real table
    'parts/part-000000.parquet': [b'PAR1 cut'],
    'recordings/mine.mcap': [b'\x89MCAP0\r\n'],
    '.cvt_sweep.json': [b'{"files": {"summary.png": "0000"}}', b'[1, 2]', b'\xff'],
    'notes.txt': [b'keep me'],
}


@FUZZ
@given(data=st.data())
def test_sweep_output_folders(worker, cluster, finished, tmp_path_factory, data):
    campaign, made = finished
    folder = tmp_path_factory.mktemp('sweep')
    out = folder / 'out'
    shape = data.draw(sometimes(0.15, st.sampled_from(['file', 'link to file', 'missing parent',
                                                       'nested']),
                                st.sampled_from(['folder', 'folder', 'none'])))
    if shape == 'file':
        out.write_bytes(b'a file of mine')
    elif shape == 'link to file':
        (folder / 'target').write_bytes(b'mine')
        out.symlink_to(folder / 'target')
    elif shape == 'missing parent':
        out = folder / 'no' / 'such' / 'out'
    elif shape == 'nested':
        (folder / 'plain').write_bytes(b'mine')
        out = folder / 'plain' / 'out'
    elif shape == 'folder':
        out.mkdir()
        for name in data.draw(st.lists(st.sampled_from(sorted(CONTENT)), unique=True)):
            content = data.draw(st.sampled_from(CONTENT[name]))
            (out / name).parent.mkdir(parents=True, exist_ok=True)
            if content is None:
                content = campaign.read_bytes()
            elif content in ('own', 'other'):
                content = (made / ('out' if content == 'own' else 'other')
                           / 'results.parquet').read_bytes()
            (out / name).write_bytes(content)
    overwrite = data.draw(st.booleans())
    argv = ['sweep', campaign, '--out', out, '--scheduler', cluster, '--quiet']
    if overwrite:
        argv.append('--overwrite')
    if data.draw(st.booleans()):
        argv.append('--retry-failed')
    # the sweep's own outputs may change; a user's campaign.yaml / summary.png only with
    # --overwrite; nothing else (a junk table, a part, a recording, notes) ever
    own = {'out/results.parquet'} if not (out / 'results.parquet').exists() or \
        (out / 'results.parquet').read_bytes() == (made / 'out/results.parquet').read_bytes() \
        else set()
    if overwrite:
        own |= {'out/campaign.yaml', 'out/summary.png'}
    record = out / '.cvt_sweep.json'
    if overwrite or not record.exists() or record.read_bytes().startswith(b'{"files"'):
        own.add('out/.cvt_sweep.json')   # (absent, or a record in the sweep's own form)
    outcome = check(worker, FOLDERS, folder, argv, own | {'out/parts'})
    assert outcome.code in (0, 2)
