"""`cvt-sim bench` end to end on a tiny configuration: the report's structure, its tables, its
numbers and plots, and that it leaves the other sections of BENCHMARKS.md alone. No timing
assertions (the numbers are measured, not promised, here)."""
import csv
import math
import re

import pytest

from cvt_ros.bench import main as bench
from cvt_ros.bench.report import write_report
from cvt_ros.bench.work_precision import METHODS
from cvt_ros.scene import available_scenes
from cvt_ros.solver import cvode

TINY = ['--quick', '--scenes', 'paper', '--duration', '0.2', '--rtols', '1e-5', '1e-7',
        '--scipy-rtols', '1e-5', '1e-7', '--steps', '5e-4', '2e-4',
        '--hard-scenes', 'paper', 'grazing',
        '--hard-duration', '0.2', '--stiffness', '500', '--stability-duration', '0.2',
        '--long-duration', '2', '--steady-span', '1', '--steady-scenes', 'paper',
        '--scaling-spans', '1', '2', '--scaling-stiffnesses', '1e3', '1e6',
        '--stiffness-span', '0.05', '--sweep-span', '0.05']

FOREIGN = """# Benchmarks

## Work-precision

STALE numbers from an earlier run

## ROS node

Node numbers | kept | as they are

```sh
# a comment in a code block is not a heading
```

## Recording

Recorder numbers.
"""


def cells(line):
    return [c.strip() for c in re.split(r'(?<!\\)\|', line.strip())[1:-1]]


def tables(text):
    """Markdown tables as (header, rows) with the cells split on unescaped pipes."""
    out, current = [], None
    for line in text.splitlines():
        if line.startswith('|'):
            if current is None:
                current = (cells(line), [])
            elif not set(line) <= set('|-'):
                current[1].append(cells(line))
        elif current is not None:
            out.append(current)
            current = None
    if current is not None:
        out.append(current)
    return out


def number(text):
    m = re.search(r'[-+]?\d+(\.\d*)?([eE][-+]?\d+)?', text)
    assert m, f'no number in {text!r}'
    return float(m.group(0))


@pytest.fixture(scope='module')
def report(tmp_path_factory):
    tmp = tmp_path_factory.mktemp('bench')
    out = tmp / 'BENCHMARKS.md'
    out.write_text(FOREIGN)
    assert bench.main(TINY + ['--write', str(out), '--plots', str(tmp / 'plots')]) == 0
    return out.read_text(), tmp


def _targets(argv, now='20250101-000000'):
    return bench.output_targets(bench.parse_args(argv), now=now)


def test_without_an_output_option_bench_writes_a_new_report_not_the_published_one(
        tmp_path, monkeypatch):
    """Issue 34: `cvt-sim bench --quick` in the checkout rewrote BENCHMARKS.md and docs/plots;
    the published files change only with --write."""
    monkeypatch.chdir(tmp_path)
    (tmp_path / 'BENCHMARKS.md').write_text(FOREIGN)
    (tmp_path / 'bench-20250101-000000.md').write_text('an earlier report')
    out, plots, update = _targets(['--quick'])
    assert (out, plots, update) == (bench.Path('bench-20250101-000000-2.md'),
                                    bench.Path('bench-20250101-000000-2-plots'), False)
    out, plots, update = _targets(['--write', 'BENCHMARKS.md'])
    assert (out, plots, update) == (bench.Path('BENCHMARKS.md'), bench.Path('docs/plots'), True)


@pytest.mark.parametrize('argv, reason', [
    (['--out', 'BENCHMARKS.md'], 'exists (use --overwrite'),
    (['--out', 'report.txt'], '.md file'),
    (['--out', 'no/such/folder/report.md'], 'no such directory'),
    (['--write', 'BENCHMARKS.md', '--plots', 'BENCHMARKS.md'], 'not a directory'),
])
def test_a_target_bench_cannot_use_is_refused_before_any_work(tmp_path, monkeypatch, capsys,
                                                              argv, reason):
    monkeypatch.chdir(tmp_path)
    (tmp_path / 'BENCHMARKS.md').write_text(FOREIGN)
    assert bench.main(TINY + argv) == 2
    assert reason in capsys.readouterr().err
    assert (tmp_path / 'BENCHMARKS.md').read_text() == FOREIGN
    assert sorted(p.name for p in tmp_path.iterdir()) == ['BENCHMARKS.md']


OWN = ('## Speed at steady state', '## Scaling', '## Clutch switches at every tolerance',
       '## Default settings', '## Work-precision',
       '## Speed-up at equal error', '## Numerical stability on hard cases',
       '## Stability limit of fixed-step RK4', '## Long run', '## Known defects')


def test_every_section_states_command_revision_machine_and_load(report):
    text, _ = report
    assert text.startswith('# Benchmarks\n')
    lines = text.splitlines()
    for title in OWN:
        at = next(i for i, line in enumerate(lines) if line.startswith(title))
        line = lines[at + 2]
        assert line.startswith('`cvt-sim bench --quick --scenes paper'), (title, line)
        for what in ('cores', 'Python 3.', 'numpy', 'scipy', 'numba', 'UTC', 'load average'):
            assert what in line, (title, what)


def test_report_has_every_section_once_and_keeps_the_others(report):
    text, _ = report
    for title in OWN + ('## ROS node', '## Recording'):
        assert text.count(title) == 1, title
    assert 'STALE' not in text
    # the file's title block stays first; the node's and the recorder's sections after ours,
    # verbatim
    assert text.index('# Benchmarks') < text.index('## Speed at steady state')
    assert text.index('## Known defects') < text.index('## ROS node') < text.index('## Recording')
    assert FOREIGN[FOREIGN.index('## ROS node'):] in text


def test_a_run_of_some_sections_replaces_those_where_they_stand(tmp_path):
    """--write with a --sections subset: the file's summary (title block), the sections the run
    did not make and other benchmarks' sections stay as they are, in their places."""
    path = tmp_path / 'BENCHMARKS.md'
    path.write_text('# Benchmarks\n\n| summary | kept |\n\n## Speed at steady state (200 s)\n\n'
                    'old steady\n\n## ROS node\n\nnode\n\n## Long run (1 h simulated)\n\n'
                    'old long\n\n## Recording\n\nrec\n')
    write_report(path, '# Benchmarks\n\nnew title block\n\n## Long run (60 s simulated)\n\n'
                       'new long\n\n## Known defects\n\nnew defects\n')
    text = path.read_text()
    assert 'new title block' not in text and '| summary | kept |' in text
    assert 'old long' not in text and 'old steady' in text
    order = ['| summary', '## Speed at steady state (200 s)', '## ROS node',
             '## Long run (60 s simulated)', 'new long', '## Known defects', '## Recording']
    assert [text.index(x) for x in order] == sorted(text.index(x) for x in order)
    write_report(path, '# Benchmarks\n\nx\n\n## Known defects\n\nagain\n', keep_others=False)
    assert path.read_text() == '# Benchmarks\n\nx\n\n## Known defects\n\nagain\n'


def test_every_point_of_every_curve_is_in_the_csv(report):
    text, tmp = report
    assert '](plots/work_precision.csv)' in text
    with open(tmp / 'plots' / 'work_precision.csv') as f:
        rows = list(csv.DictReader(f))
    checked = 0
    for row in rows:
        if row['status'] != 'ok':
            continue
        wall, rtf, err = float(row['wall_s']), float(row['rtf']), float(row['phi4_rel_error'])
        assert wall > 0.0 and rtf > 0.0 and err > 0.0
        assert rtf == pytest.approx(0.2 / wall, rel=0.01)
        checked += 1
    # every method, both settings (CVODE's only when scikit-sundae is installed)
    ran = [m for m in METHODS if not m.cvode or cvode.available() is None]
    assert checked == 2 * len(ran)
    assert {row['method'] for row in rows} == {m.label for m in ran}
    for name in ('speed_up.csv', 'hard_cases.csv', 'long_run.csv'):
        with open(tmp / 'plots' / name) as f:
            assert len(list(csv.reader(f))) > 2, name


def test_tables_are_well_formed(report):
    text, _ = report
    found = tables(text)
    assert len(found) >= 10
    for header, rows in found:
        for row in rows:
            assert len(row) == len(header), (header, row)


def test_default_settings_and_speed_up_are_numbers(report):
    text, _ = report
    default = next(t for t in tables(text) if t[0][0] == 'settings')
    for row in default[1]:
        assert number(row[1]) > 0.0 and number(row[-1]) > 0.0     # φ4 error, real-time factor
    speedup = next(t for t in tables(text) if t[0][:3] == ['scene', 'φ4 error', 'project (RTF)'])
    assert [r[1] for r in speedup[1]] == ['1e-04', '1e-06', '1e-08']
    ratios = [c for r in speedup[1] for c in r[3:] if not c.startswith(('n/r', '–'))]
    assert ratios and all(number(c) > 0.0 for c in ratios)


def test_stability_limit_and_long_run_rows(report):
    text, _ = report
    limits = next(t for t in tables(text) if t[0][0] == 'formulation')
    assert [r[0] for r in limits[1]] == ['reduced', 'paper']
    for row in limits[1]:
        theory, limit = number(row[3]), number(row[4])
        assert 0.0 < limit < 10.0 * theory
    long = next(t for t in tables(text) if t[0][0] == 'run')
    for row in long[1]:
        assert number(row[1]) > 0.0 and math.isfinite(number(row[4]))


def test_steady_state_and_scaling_rows(report):
    text, _ = report
    steady = next(t for t in tables(text) if t[0][:2] == ['scene', 'wall [ms]'])
    assert [r[0] for r in steady[1]] == ['paper']
    wall, scipy_wall = (number(steady[1][0][i]) for i in (1, 4))
    assert wall > 0.0 and scipy_wall > 0.0
    sequential, independent = (number(part) for part in steady[1][0][9].split('/'))
    assert sequential >= 1.0 and independent >= 1.0   # each floor is a floor
    loose = next(t for t in tables(text) if t[0][:3] == ['scene', 'wall [ms]', 'φ4 rel. error'])
    assert [r[0] for r in loose[1]] == ['paper'] and number(loose[1][0][4]) > 0.0
    times = next(t for t in tables(text) if t[0][0] == 'simulated [s]')
    assert [number(r[0]) for r in times[1]] == [1.0, 2.0]
    # a scene whose four variants switch alike at every rtol is one entry of a sentence, any
    # other has a row per variant
    sweep = next((t for t in tables(text) if t[0][:2] == ['scene', 'variant']), (None, []))
    clean = re.search(r'none late: (.*)\.\n', text)
    named = [entry.split()[0] for entry in clean.group(1).split(', ')] if clean else []
    listed = [r[0] for r in sweep[1]]
    assert set(named) | set(listed) == set(available_scenes(n_paths=1))
    assert all(listed.count(s) == 4 for s in listed) and not set(named) & set(listed)
    assert all(r[3] == 'same' for r in sweep[1])


def test_plots_are_pngs_linked_from_the_report(report):
    text, tmp = report
    for name in ('work_precision_paper.png', 'stability_limit.png'):
        path = tmp / 'plots' / name
        assert path.read_bytes()[:8] == b'\x89PNG\r\n\x1a\n'
        assert path.stat().st_size > 10_000
        assert f'](plots/{name})' in text
