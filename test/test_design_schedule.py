"""The gain schedule (``cvt-sim identify --grid``) on the Dask sweep engine: each operating
point's row equals identify at that point run here (the same code through a worker process),
the table resumes, a grid beyond its time budget and a bad grid are refused before any cluster
starts."""
import math

import pytest

from cvt_ros.cli import main
from cvt_ros.design.errors import DesignError
from cvt_ros.design.identify import IdentifySettings, identify
from cvt_ros.design.schedule import figures_of, parse_grid, run_schedule

pytest.importorskip('distributed')
COARSE = IdentifySettings(sweep=False, sample_dt=4e-3, fit_dt=8e-3)


def test_grid_rows_equal_identify_at_each_point(tmp_path):
    axes = [('linkage.crank_length', [0.03, 0.04])]
    result = run_schedule('conveyor', axes, tmp_path, {'load.torque': 6.0}, COARSE, workers=1)
    assert [r['status'] for r in result.rows] == ['ok', 'ok']
    row = result.rows[1]
    here = figures_of(identify('conveyor', {'load.torque': 6.0, 'linkage.crank_length': 0.04},
                               COARSE))
    for name, value in here.items():
        assert row[name] == value or (math.isnan(value) and math.isnan(row[name])), name
    assert result.csv.read_text().count('\n') == 3 and result.figure.stat().st_size > 10_000
    # a rerun finds every point in the table and starts no cluster
    again = run_schedule('conveyor', axes, tmp_path, {'load.torque': 6.0}, COARSE, workers=1,
                         time_budget=1e-3)
    assert [r['case_id'] for r in again.rows] == [r['case_id'] for r in result.rows]


def test_a_grid_beyond_its_time_budget_is_refused_before_it_runs(tmp_path):
    axes = [('linkage.crank_length', [0.03, 0.035, 0.04]), ('load.torque', [4.0, 8.0])]
    with pytest.raises(DesignError, match='--time-budget 1 s'):
        run_schedule('conveyor', axes, tmp_path, None, COARSE, workers=1, time_budget=1.0)
    assert not (tmp_path / 'results.parquet').exists()


@pytest.mark.parametrize('grid, words', [
    (['linkage.crank_length=0.02,abc'], 'LOW:HIGH:NUM'),
    (['linkage.crank_length=0.02:0.04:0'], 'NUM'),
    (['load.torque=1e9'], 'load.torque'),
    (['motor.model=induction'], 'not a numeric'),
    (['nonsense'], 'NAME=VALUES'),
    (['load.torque=1,2', 'load.torque=3'], 'twice'),
    (['linkage.crank_length=0:0.09:1000', 'load.torque=0:10:1000'], 'operating points'),
])
def test_bad_grids_are_refused(grid, words):
    with pytest.raises(DesignError, match=words):
        parse_grid(grid)


def test_cli_grid_needs_a_folder(tmp_path, capsys):
    assert main(['identify', 'conveyor', '--grid', 'load.torque=4,8']) == 2
    file = tmp_path / 'file'
    file.write_text('x')
    assert main(['identify', 'conveyor', '--grid', 'load.torque=4,8', '--out', str(file)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 2 and '--out' in err[0] and 'not a folder' in err[1]
