"""The command line as a user runs it: real processes, real files."""
import argparse
import csv
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from cvt_ros.solver.output import CSV_COLUMNS

CLI = [sys.executable, '-m', 'cvt_ros']


def cvt_sim(*args, check=True):
    proc = subprocess.run([*CLI, *args], capture_output=True, text=True, timeout=300)
    if check:
        assert proc.returncode == 0, proc.stderr
    return proc


def test_run_writes_the_csv_columns_on_a_uniform_grid(tmp_path):
    out = tmp_path / 'paper.csv'
    proc = cvt_sim('run', 'paper', '--duration', '0.5', '--sample-dt', '0.002', '--csv', str(out),
                   '--set', 'load.torque=4.0')
    with out.open() as f:
        header = next(csv.reader(f))
    assert header == list(CSV_COLUMNS)
    assert header == ('t,phi1,phi2,phi3,phi4,omega1,omega2,omega3,omega4,engaged,twist,'
                      'clutch_torque,crank_length,load_torque').split(',')
    data = np.loadtxt(out, delimiter=',', skiprows=1)
    assert data.shape == (251, 14)
    assert data[0, 0] == 0.0
    assert np.allclose(np.diff(data[:, 0]), 0.002, atol=1e-12)
    assert set(np.unique(data[:, 9])) <= {0.0, 1.0}
    assert np.all(data[:, 13] == 4.0)          # --set reached the model
    assert data[0, 5] == 150.0                  # ω1(0) = initial.crank_speed
    for key in ('mean ratio', 'clutch switches', 'energy balance', 'wall time',
                'real-time factor'):
        assert key in proc.stdout


def test_console_script_and_module_are_the_same_program():
    script = Path(sys.executable).with_name('cvt-sim')
    assert script.exists()
    a = subprocess.run([str(script), '--help'], capture_output=True, text=True, timeout=60)
    b = cvt_sim('--help')
    assert a.returncode == 0 and a.stdout == b.stdout
    assert 'cvt-sim run paper --duration 10' in a.stdout
    run_help = cvt_sim('run', '--help').stdout
    assert '--set KEY=VALUE' in run_help and '--sample-dt' in run_help


@pytest.mark.parametrize('args, fragment', [
    (('run', 'paper', '--duration', '1', '--set', 'linkage.crank_length=0.2'), 'Grashof'),
    (('run', 'paper', '--duration', '1', '--set', 'inertia.outptu=1'), 'did you mean'),
    (('run', 'nowhere', '--duration', '1'), 'not found'),
    (('run', 'paper', '--duration', '-1'), 'positive'),
    (('run', 'paper', '--duration', '1', '--set', 'load.torque'), 'key=value'),
    (('run', 'paper', '--duration', '1', '--csv', '/nonexistent/x.csv'),
     '/nonexistent/x.csv: no such directory /nonexistent'),
    (('run', 'paper', '--duration', '1', '--csv', '/'), '/: is a directory, not a file'),
])
def test_bad_input_is_one_clear_line_and_exit_2(args, fragment):
    proc = cvt_sim(*args, check=False)
    assert proc.returncode == 2
    assert fragment in proc.stderr
    assert 'Traceback' not in proc.stderr


def test_the_averaged_model_prints_no_switches_or_peaks_it_cannot_have():
    out = cvt_sim('run', 'paper', '--duration', '1', '--fidelity', 'averaged', '--quiet').stdout
    assert 'clutch switches  n/a: the averaged model has no clutch events' in out
    assert 'peaks            n/a: the averaged model follows cycle means' in out


def test_params_lists_every_parameter_with_its_unit():
    out = cvt_sim('params').stdout
    assert 'linkage.crank_length' in out and 'N*m/rad' in out
    assert "one of ['reduced', 'paper']" in out


def test_demo_runs_the_paper_scene_end_to_end():
    proc = cvt_sim('demo')
    assert 'paper' in proc.stdout and 'mean ratio i' in proc.stdout


def test_progress_bar_stays_off_a_short_run_and_out_of_stdout(tmp_path):
    proc = cvt_sim('run', 'paper', '--duration', '0.2')
    assert '%|' not in proc.stderr and '%|' not in proc.stdout
    env = dict(os.environ)
    assert env.get('AMENT_PREFIX_PATH')


def _help_texts(parser):
    """The --help text of a parser and of every subcommand under it."""
    yield parser.format_help()
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for sub in action.choices.values():
                yield from _help_texts(sub)


def test_files_named_in_help_texts_exist():
    """An example in --help that names a shipped file names one that is there (the sweep
    example once named a campaign that had been renamed)."""
    from cvt_ros.cli.cvt_sim import build_parser
    from cvt_ros.device.main import build_parser as node_parser
    root = Path(__file__).resolve().parent.parent
    texts = [*_help_texts(build_parser()), node_parser().format_help()]
    named = {m for text in texts for m in re.findall(
        r'(?<![\w/.])((?:config|docs|launch)/[\w./-]*\.(?:yaml|md|py|png|json|csv))', text)}
    assert 'docs/node.md' in named and len(named) > 5
    assert not [p for p in named if not (root / p).exists()]
