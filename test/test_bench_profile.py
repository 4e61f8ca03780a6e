"""cvt-sim bench profile: the pieces that do not need perf (which a CI machine may lack): the
perf map of freshly compiled kernels, numba's names read back, perf's report parsed, and the
section put into a markdown file in place of the old one."""
import os

from numba import njit

from cvt_ros.bench import profile
from cvt_ros.bench.report import replace_section


@njit(cache=False)
def _crank_torque_for_the_map(x):
    return 2.0 * x + 1.0


def test_a_kernel_compiled_here_is_in_the_perf_map_under_its_own_name(tmp_path):
    assert _crank_torque_for_the_map(1.0) == 3.0
    entries = profile.perf_map_entries()
    names = {profile.kernel_name(name) for _, _, name in entries}
    assert f'{__name__}._crank_torque_for_the_map' in names
    addresses = [a for a, _, _ in entries]
    assert addresses == sorted(addresses) and all(size > 0 for _, size, _ in entries)
    path = profile.write_perf_map(entries, pid=f'test{os.getpid()}')
    try:
        lines = open(path).read().splitlines()
        assert len(lines) == len(entries)
        address, size, name = lines[0].split(' ', 2)
        assert int(address, 16) == entries[0][0] and int(size, 16) > 0
    finally:
        os.remove(path)


def test_numba_names_read_back_and_other_rows_labelled():
    mangled = ('_ZN7cvt_ros6solver8steppers11dopri5_stepB3v54B102c8tJTIeFIjxB2IKSgI4CrvSCKg1M'
               'MbCQQPKkLTj8gEEF9aYtuj_2br1RPT8tR1FNST8_2fNKihKTS0DsxKLkAhCdV1ylXqupCQA_3dE')
    assert profile.kernel_name(mangled) == 'cvt_ros.solver.steppers.dopri5_step'
    assert profile.kernel_name('_ZN7cpython7cvt_ros6solver6hybrid7advanceB3v1E') == (
        'cpython cvt_ros.solver.hybrid.advance')
    assert profile.kernel_name('cfunc._ZN7cvt_ros7physics8dynamics3rhsB3v1E') == (
        'cfunc cvt_ros.physics.dynamics.rhs')
    assert profile.kernel_name('_PyEval_EvalFrameDefault') is None
    assert profile.label('libm.so.6', '__sincos_fma') == 'libm sincos'
    assert profile.label('[kernel.kallsyms]', 'exc_page_fault').startswith('operating system')
    assert profile.label('libpython3.11.so.1.0', '_PyEval_EvalFrameDefault').startswith('Python')
    assert profile.label('_multiarray_umath.cpython-311-x86_64-linux-gnu.so', 'x') == 'numpy'


REPORT = """\
# Samples: 10K of event 'cpu-clock:u'
#
# Overhead       Samples  Shared Object      Symbol
# ........  ............  .................  ......
#
    20.20%          2717  [JIT] tid 734      [.] _ZN7cvt_ros7physics8dynamics3rhsB3v13B1E
     8.97%          1207  libm.so.6          [.] __sincos_fma
     8.50%          1144  [JIT] tid 734      [.] _ZN7cvt_ros6solver8steppers11dopri5_stepB3v5E
     0.40%            54  [JIT] tid 734      [.] _ZN7cvt_ros6solver8steppers11dopri5_stepB3v6E
     0.31%            42  [kernel.kallsyms]  [k] do_syscall_64
"""


def test_a_perf_report_is_summed_per_kernel():
    counts = profile.parse_report(REPORT)
    assert counts['cvt_ros.physics.dynamics.rhs'] == 2717
    assert counts['cvt_ros.solver.steppers.dopri5_step'] == 1144 + 54   # two copies, one kernel
    assert counts['libm sincos'] == 1207
    assert sum(counts.values()) == 2717 + 1207 + 1144 + 54 + 42
    window = {'scene': 'paper', 'start': 10.0, 'stop': 12.0, 'span': 2000.0, 'rhs': 7,
              'steps': 1}
    text = profile.section([(window, counts)], 'cvt-sim bench profile', '0.1 at the start')
    assert text.startswith(profile.TITLE)
    assert '| `cvt_ros.physics.dynamics.rhs` | 52.6 % |' in text   # 2717 of 5164
    assert '| µs per simulated second (wall) | 1000 |' in text


def test_the_section_replaces_its_old_self_and_keeps_the_others(tmp_path):
    path = tmp_path / 'BENCHMARKS.md'
    path.write_text('# Benchmarks\n\nintro\n\n## A\n\na\n\n' + profile.TITLE + '\n\nold\n\n'
                    '## B\n\nb\n')
    replace_section(path, profile.TITLE, profile.TITLE + '\n\nnew\n')
    text = path.read_text()
    assert 'old' not in text and text.count(profile.TITLE) == 1
    assert text.index('## A') < text.index('new') < text.index('## B')
    replace_section(path, '## C', '## C\n\nc\n')
    assert path.read_text().rstrip().endswith('## C\n\nc')
