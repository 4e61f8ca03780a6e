"""One case at a time, in this process: figures from the analysis room, every failure a row
(the campaign goes on), per-case recordings, the Parquet table (parts, merge, resume) and the
summary plot."""
import math
import textwrap

import numpy as np
import pyarrow.parquet as pq
import pytest

from cvt_ros.analysis import load
from cvt_ros.sweep import build_tasks, load_campaign, run_case
from cvt_ros.sweep.cluster import plan_campaign
from cvt_ros.sweep.plots import plot_summary, title_notes
from cvt_ros.sweep.table import TableError


def campaign_file(tmp_path, text, name='c.yaml'):
    path = tmp_path / name
    path.write_text(textwrap.dedent(text))
    return load_campaign(path)


SHORT = """\
    scene: conveyor
    duration: 4.0
    vary:
      linkage.crank_length: [0.02, 0.04]
      load.torque: [4.0, 8.0]
    metrics: [mean_ratio, efficiency, peak_clutch_torque, switches_per_second, energy_residual,
              run_peak_clutch_torque]
    """


@pytest.fixture(scope='module')
def short_rows(tmp_path_factory):
    campaign = campaign_file(tmp_path_factory.mktemp('short'), SHORT)
    return campaign, [run_case(t) for t in build_tasks(campaign)]


def test_scene_case_figures(short_rows):
    _, rows = short_rows
    assert [r['status'] for r in rows] == ['ok'] * 4
    for r in rows:
        assert r['steady'] is True and 0.5 < r['window_start'] < 4.0
        assert 0.9 < r['efficiency'] < 1.0
        assert r['energy_residual'] < 1e-4
        # two switches per crank turn, the crank at ~25 turns per second
        assert 40 < r['switches_per_second'] < 110
        assert r['run_peak_clutch_torque'] >= r['peak_clutch_torque'] > 0
        assert r['wall_time'] > 0 and r['error'] == '' and r['failure'] == ''
    ratio = {(r['linkage.crank_length'], r['load.torque']): r['mean_ratio'] for r in rows}
    # the ratio grows with the crank length and falls a little with the load (ratio map)
    assert ratio[(0.04, 4.0)] > 1.8 * ratio[(0.02, 4.0)]
    assert ratio[(0.04, 8.0)] < ratio[(0.04, 4.0)]


def test_every_failure_is_a_row_with_its_reason(tmp_path):
    campaign = campaign_file(tmp_path, """\
        scene: conveyor
        duration: 1.0
        overrides: {solver.method: rk4, solver.fixed_step: 0.02, shaft.stiffness: 1.0e5}
        cases:
          - {solver.refine_step: auto}
          - {solver.refine_step: 'off'}
        """)
    ok, diverged = [run_case(t) for t in build_tasks(campaign)]
    assert ok['status'] == 'ok' and math.isfinite(ok['mean_ratio'])
    assert diverged['status'] == 'failed' and diverged['failure'] == 'diverged'
    assert 'non-finite state' in diverged['error'] and math.isnan(diverged['mean_ratio'])
    assert diverged['steady'] is None


def test_a_case_past_its_time_budget_is_stopped(tmp_path):
    campaign = campaign_file(tmp_path, """\
        scene: conveyor
        duration: 20.0
        time_budget: 1.0e-6        # s: no case can be that fast
        vary: {load.torque: [8.0]}
        """)
    row = run_case(build_tasks(campaign)[0])
    assert row['status'] == 'failed' and row['failure'] == 'timeout'
    assert 'exceeded its time budget of 1e-06 s' in row['error']
    assert ' of 20 s simulated' in row['error']


def test_scenario_case_step_metrics_and_a_raising_controller(tmp_path):
    gains = campaign_file(tmp_path, """\
        scenario: conveyor_load_step
        duration: 6.0
        vary: {controller.kp: [2.0e-3]}
        record: mcap
        """, 'gains.yaml')
    task = build_tasks(gains, tmp_path / 'out')[0]
    row = run_case(task)
    assert row['status'] == 'ok', row['error']
    assert row['max_deviation'] < 1.0 and 45 < row['switches_per_second'] < 70
    assert row['energy_residual'] < 1e-3 and row['iae'] > 0
    traces, _ = load(task.record)   # the per-case recording reads back as a recording
    assert traces[0].t[-1] == pytest.approx(6.0)
    bad = campaign_file(tmp_path, """\
        scenario: conveyor_load_step
        duration: 2.0
        controller: sweep_controllers:raising
        vary: {load.viscous: [0.05, 0.1]}
        """, 'bad.yaml')
    rows = [run_case(t) for t in build_tasks(bad)]
    assert [r['failure'] for r in rows] == ['controller', 'controller']
    assert 'ZeroDivisionError' in rows[0]['error'] and 't = 0.50' in rows[0]['error']
    broken = campaign_file(tmp_path, """\
        scenario: conveyor_load_step
        duration: 2.0
        controller: sweep_controllers:broken_factory
        vary: {load.viscous: [0.05]}
        """, 'broken.yaml')
    row = run_case(build_tasks(broken)[0])
    assert row['failure'] == 'error' and row['error'].startswith('HarnessError: ')
    assert "broken_factory() raised RuntimeError('no gains file')" in row['error']


def test_table_parts_merge_and_resume(tmp_path, short_rows):
    campaign, rows = short_rows
    out = tmp_path / 'out'
    plan = plan_campaign(campaign, out)
    assert len(plan.todo) == 4 and plan.skipped == 0
    plan.store.add(rows[2])
    plan.store.flush()
    plan.store.add(rows[0])
    plan.store.flush()
    (out / 'parts' / 'part-000099.parquet').write_bytes(b'PAR1 cut off')   # damaged on disk
    again = plan_campaign(campaign, out)
    assert [t.index for t in again.todo] == [1, 3]
    assert again.store.problems and 'part-000099' in again.store.problems[0]
    merged = again.store.merge(again.order)
    # the merged parts are gone; the unreadable one is left as it was (and reported)
    assert [r['case'] for r in merged] == [0, 2]
    assert [p.name for p in (out / 'parts').iterdir()] == ['part-000099.parquet']
    table = pq.read_table(out / 'results.parquet')
    assert table.column_names[:4] == ['case', 'case_id', 'linkage.crank_length', 'load.torque']
    assert table.schema.field('peak_clutch_torque').metadata[b'unit'] == b'N*m'
    assert b'conveyor' in table.schema.metadata[b'cvt_ros.campaign']
    assert [t.index for t in plan_campaign(campaign, out).todo] == [1, 3]
    # record: added to the campaign: the cases done without a recording run again to make it
    recorded = campaign_file(tmp_path, SHORT.rstrip(' ') + '    record: csv\n', 'r.yaml')
    assert [t.index for t in plan_campaign(recorded, out).todo] == [0, 1, 2, 3]
    # the folder of another campaign is refused before anything runs
    other = campaign_file(tmp_path, SHORT.replace('duration: 4.0', 'duration: 5.0'), 'o.yaml')
    with pytest.raises(TableError, match='2 of its 2 cases are not cases of'):
        plan_campaign(other, out)


def test_summary_plot_grid_and_scatter(tmp_path, short_rows):
    campaign, rows = short_rows
    rows = [dict(r) for r in rows]
    rows[3].update(status='failed', mean_ratio=math.nan)
    assert plot_summary(campaign, rows, tmp_path / 'grid.png') == tmp_path / 'grid.png'
    assert (tmp_path / 'grid.png').read_bytes()[:4] == b'\x89PNG'
    scattered = campaign_file(tmp_path, """\
        scene: conveyor
        duration: 1.0
        sampling: latin_hypercube
        samples: 6
        vary:
          linkage.crank_length: {range: [0.02, 0.08]}
          load.torque: {range: [0, 10]}
        """, 's.yaml')
    fake = [dict(t.variables, case=t.index, status='ok', mean_ratio=float(v), efficiency=0.9)
            for t, v in zip(build_tasks(scattered), np.linspace(0.2, 0.8, 6), strict=True)]
    assert plot_summary(scattered, fake, tmp_path / 'scatter.png') is not None
    # a third varied parameter the two axes cannot show: the title says so
    three = campaign_file(tmp_path, SHORT.replace(
        'load.torque: [4.0, 8.0]', 'load.torque: [4.0, 8.0]\n      shaft.damping: [0.0, 0.1]'),
        't.yaml')
    rows3 = [dict(t.variables, case=t.index, status='ok', mean_ratio=0.3, efficiency=0.9)
             for t in build_tasks(three)]
    notes = title_notes(three, rows3, 'linkage.crank_length', 'load.torque')
    assert any(n.startswith('shaft.damping also varied, not told apart') for n in notes)
    assert not any('also varied' in n for n in title_notes(campaign, rows,
                                                            'linkage.crank_length',
                                                            'load.torque'))


def test_an_unphysical_figure_is_kept_with_a_warning(tmp_path):
    """No load, no damping: output and motor work are both the inertias' give and take, and
    their ratio came out 1.0004 — stored as an efficiency with no word. Now the case's warnings
    say what cvt-sim analyze says of it."""
    campaign = campaign_file(tmp_path, """\
        scene: conveyor
        duration: 4.0
        vary:
          linkage.crank_length: [0.02]
          load.torque: [0.0]
          shaft.damping: [0.0]
        """)
    (row,) = [run_case(t) for t in build_tasks(campaign)]
    assert row['status'] == 'ok'
    assert not 0.0 <= row['efficiency'] <= 1.0, row['efficiency']
    assert 'efficiency outside 0–100 %' in row['warnings'], row['warnings']


def test_a_scenario_window_leaves_the_start_up_out(tmp_path):
    """conveyor_pi_gains' kind of case (kp 3e-3, ki 5.67e-3): over the whole run the start-up
    from rest decides two figures — its clutch impact is the peak torque of every case, and
    it has not settled when the set point changes at 2 s, so the worst settling time is NaN.
    From 2 s on they are the set-point steps' own."""
    def row(window):
        campaign = campaign_file(tmp_path, f"""\
            scenario: conveyor_setpoint_steps
            {window}
            cases: [{{controller.kp: 3.0e-3, controller.ki: 5.67e-3}}]
            metrics: [settling_time, peak_clutch_torque, iae]
            """, f'w{len(window)}.yaml')
        result = run_case(build_tasks(campaign)[0])
        assert result['status'] == 'ok', result['error']
        return result
    whole, steps = row(''), row('window: {start: 2.0}')
    assert math.isnan(whole['settling_time']) and whole['peak_clutch_torque'] > 1000.0
    assert 1.0 < steps['settling_time'] < 6.0
    assert 0.0 < steps['peak_clutch_torque'] < 0.5 * whole['peak_clutch_torque']
    assert 0.0 < steps['iae'] < whole['iae']
