"""A sweep's output folder (issue 34): `cvt-sim sweep CAMPAIGN --out DIR` silently replaced a
campaign.yaml and a summary.png of the user's in DIR. The sweep replaces them only where an
earlier sweep wrote them; everything else is refused before a case runs (or replaced with
--overwrite). The cases are run here in-process, so that no cluster is needed: a rerun whose
cases are all in the table runs none."""
import textwrap

import pytest

from cvt_ros.cli import main as cvt_sim
from cvt_ros.sweep.campaign import load_campaign
from cvt_ros.sweep.cases import build_tasks
from cvt_ros.sweep.cluster import plan_campaign
from cvt_ros.sweep.errors import CampaignError
from cvt_ros.sweep.runner import run_case
from cvt_ros.sweep.table import TableError

TINY = """\
    name: tiny
    scene: conveyor
    duration: 0.1
    vary: {load.torque: [4.0, 8.0]}
    """


@pytest.fixture
def done(tmp_path):
    """The tiny campaign and a folder whose table holds all its cases (nothing left to run)."""
    path = tmp_path / 'tiny.yaml'
    path.write_text(textwrap.dedent(TINY))
    campaign = load_campaign(path)
    out = tmp_path / 'out'
    plan = plan_campaign(campaign, out)
    for task in plan.tasks:
        plan.store.add(run_case(task))
    plan.store.merge(plan.order)
    return path, out


def sweep(capsys, *argv):
    code = cvt_sim(['sweep', *map(str, argv), '--quiet'])
    out, err = capsys.readouterr()
    assert 'Traceback' not in err
    return code, out, err


def test_a_rerun_replaces_only_its_own_files(done, capsys):
    path, out = done
    assert sweep(capsys, path, '--out', out)[0] == 0
    assert (out / 'campaign.yaml').read_text() == path.read_text()
    first = (out / 'summary.png').read_bytes()
    assert first[:4] == b'\x89PNG'
    assert sweep(capsys, path, '--out', out)[0] == 0      # its own files: replaced, no question
    (out / 'summary.png').write_bytes(b'\x89PNG my own annotated copy')
    code, _, err = sweep(capsys, path, '--out', out)
    assert code == 2 and "summary.png: exists and is not this sweep's output" in err
    assert (out / 'summary.png').read_bytes() == b'\x89PNG my own annotated copy'
    assert sweep(capsys, path, '--out', out, '--overwrite')[0] == 0
    assert (out / 'summary.png').read_bytes()[:4] == b'\x89PNG' and \
        (out / 'summary.png').read_bytes() != b'\x89PNG my own annotated copy'


@pytest.mark.parametrize('name, content, reason', [
    ('campaign.yaml', b'# my notes\n', "campaign.yaml: exists and is not this sweep's output"),
    ('summary.png', b'\x89PNG mine', "summary.png: exists and is not this sweep's output"),
    ('.cvt_sweep.json', b'[1, 2]', "not the sweep's record of its files"),
    ('results.parquet', b'PAR1 junk', 'not a readable results table'),
])
def test_a_users_file_where_the_sweep_writes_is_refused_before_any_case(tmp_path, capsys, name,
                                                                        content, reason):
    path = tmp_path / 'tiny.yaml'
    path.write_text(textwrap.dedent(TINY))
    out = tmp_path / 'out'
    out.mkdir()
    (out / name).write_bytes(content)
    code, _, err = sweep(capsys, path, '--out', out)
    assert code == 2 and reason in err, err
    assert (out / name).read_bytes() == content
    assert {p.name for p in out.iterdir()} <= {name, 'parts'}   # (nothing else written)


def test_another_parquet_file_is_not_taken_for_a_table(tmp_path):
    import pyarrow as pa
    import pyarrow.parquet as pq
    path = tmp_path / 'tiny.yaml'
    path.write_text(textwrap.dedent(TINY))
    out = tmp_path / 'out'
    out.mkdir()
    pq.write_table(pa.table({'x': [1, 2]}), out / 'results.parquet')
    with pytest.raises(TableError, match='not a results table of cvt-sim sweep'):
        plan_campaign(load_campaign(path), out)


@pytest.mark.parametrize('window, kind', [('{start: 0.1}', 'scene'), ('{start: 14}', 'scenario')])
def test_a_metric_window_after_the_run_is_refused(tmp_path, window, kind):
    base = 'scene: conveyor\nduration: 0.1\n' if kind == 'scene' else \
        'scenario: conveyor_setpoint_steps\n'
    path = tmp_path / 'w.yaml'
    path.write_text(f"{base}window: {window}\nvary: {{load.viscous: [0.0, 0.01]}}\n")
    with pytest.raises(CampaignError, match='window: start .* at or after the end'):
        build_tasks(load_campaign(path))


def test_a_case_without_a_step_in_its_window_says_so_in_the_table(tmp_path):
    path = tmp_path / 'w.yaml'
    path.write_text('scenario: conveyor_setpoint_steps\nduration: 9.0\nwindow: {start: 8.5}\n'
                    'vary: {load.viscous: [0.0]}\nmetrics: [overshoot, iae]\n')
    row = run_case(build_tasks(load_campaign(path))[0])
    assert row['status'] == 'ok'
    assert 'no set-point or load step from 8.5 s on' in row['warnings']
