"""Output paths of `cvt-sim analyze / export / recover` (issue 14): a bad target is one line and
exit 2 before any work, a full disk leaves no partial file behind, and no command ever writes
onto its own input."""
import os
import resource
import subprocess
import sys

import pytest
from recording_helpers import child_env

from cvt_ros.cli import main
from cvt_ros.recording import OutputError, OutputFiles

CLI = [sys.executable, '-m', 'cvt_ros']


@pytest.fixture(scope='module')
def recording(tmp_path_factory):
    d = tmp_path_factory.mktemp('outputs')
    path = d / 'v.mcap'
    assert main(['run', 'paper', '--duration', '0.6', '--quiet', '--mcap', str(path)]) == 0
    return path


def run(capsys, *args):
    code = main([str(a) for a in args])
    out, err = capsys.readouterr()
    return code, out, err.strip().splitlines()


def listing(folder):
    return sorted(p.name for p in folder.iterdir())


@pytest.mark.parametrize('command', [
    ['export', '{rec}', '--csv', '{rec}'],
    ['export', '{rec}', '--csv', '{dir}/ok.csv', '--events', '{rec}'],
    ['analyze', '{rec}', '--json', '{rec}'],
    ['analyze', '{rec}', '--cycles-csv', '{rec}'],
    ['analyze', '{rec}', '--plots', '{rec}'],
    ['recover', '{rec}', '-o', '{rec}', '--overwrite'],
    ['export', '{rec}', '--csv', '{dir}/link.csv'],          # a symlink to the recording
])
def test_no_command_writes_onto_its_input(recording, tmp_path, capsys, command):
    link = tmp_path / 'link.csv'
    link.symlink_to(recording)
    before = recording.read_bytes()
    args = [a.format(rec=recording, dir=tmp_path) for a in command]
    code, out, err = run(capsys, *args)
    assert code == 2 and len(err) == 1, err
    assert 'input' in err[0] or 'exists and is not a directory' in err[0] \
        or 'same' in err[0], err
    assert recording.read_bytes() == before
    assert listing(tmp_path) == ['link.csv']                   # nothing else was written


@pytest.mark.parametrize('option', ['--csv', '--json', '--cycles-csv', '--plots'])
def test_missing_directory_and_directory_targets(recording, tmp_path, capsys, option):
    command = 'export' if option == '--csv' else 'analyze'
    target = tmp_path / 'no' / 'such' / 'dir' / 'out'
    code, _, err = run(capsys, command, recording, option, target)
    assert code == 2 and len(err) == 1 and 'no such directory' in err[0], err
    if option != '--plots':
        code, _, err = run(capsys, command, recording, option, tmp_path)
        assert code == 2 and len(err) == 1 and 'is a directory' in err[0], err
    assert listing(tmp_path) == []


@pytest.mark.parametrize('command', [
    ['export', '{rec}', '--csv', '/dev/full'],
    ['analyze', '{rec}', '--json', '/dev/full'],
    ['analyze', '{rec}', '--cycles-csv', '/dev/full'],
    ['recover', '{rec}', '-o', '/dev/full', '--overwrite'],
])
def test_a_full_device_is_one_line_and_exit_2(recording, capsys, command):
    args = [a.format(rec=recording) for a in command]
    code, _, err = run(capsys, *args)
    assert code == 2 and len(err) == 1 and 'No space left on device' in err[0], err


def _limited(limit):
    def preexec():
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))
    return preexec


def test_a_full_disk_leaves_no_partial_file_and_keeps_old_outputs(recording, tmp_path):
    """RLIMIT_FSIZE makes every write past 30 kB fail with EFBIG, as a full disk fails: the
    small per-cycle CSV fits, the JSON does not — neither may remain (all or nothing), an
    existing JSON is kept as it was, and no temporary file is left."""
    old = tmp_path / 'old.json'
    old.write_text('{"kept": true}')
    plots = tmp_path / 'plots'
    proc = subprocess.run(
        [*CLI, 'analyze', str(recording), '--cycles-csv', str(tmp_path / 'cycles.csv'),
         '--json', str(old), '--plots', str(plots)],
        capture_output=True, text=True, timeout=300, env=child_env(),
        preexec_fn=_limited(30_000))
    err = proc.stderr.strip().splitlines()
    assert proc.returncode == 2 and len(err) == 1, proc.stderr
    assert 'File too large' in err[0] and 'no output file was written' in err[0]
    assert 'mean ratio' in proc.stdout                       # the report itself was printed
    assert listing(tmp_path) == ['old.json'] and old.read_text() == '{"kept": true}'


def test_export_onto_a_full_disk(recording, tmp_path):
    proc = subprocess.run(
        [*CLI, 'export', str(recording), '--csv', str(tmp_path / 'v.csv'), '--events',
         str(tmp_path / 'e.csv')], capture_output=True, text=True, timeout=300, env=child_env(),
        preexec_fn=_limited(20_000))
    assert proc.returncode == 2 and 'File too large' in proc.stderr, proc.stderr
    assert listing(tmp_path) == []


def test_recover_onto_a_full_disk_leaves_nothing(recording, tmp_path):
    out = tmp_path / 'r.mcap'
    proc = subprocess.run([*CLI, 'recover', str(recording), '-o', str(out)],
                          capture_output=True, text=True, timeout=300, env=child_env(),
                          preexec_fn=_limited(20_000))
    assert proc.returncode == 2 and 'File too large' in proc.stderr, proc.stderr
    assert 'Traceback' not in proc.stderr and listing(tmp_path) == []


def test_two_outputs_on_one_file_are_refused(recording, tmp_path, capsys):
    code, _, err = run(capsys, 'export', recording, '--csv', tmp_path / 'x.csv', '--events',
                       tmp_path / 'x.csv')
    assert code == 2 and 'named for two outputs' in err[0]
    code, _, err = run(capsys, 'analyze', recording, '--json', tmp_path / 'x',
                       '--cycles-csv', tmp_path / 'x')
    assert code == 2 and 'named for two outputs' in err[0]
    assert listing(tmp_path) == []


def test_plots_directory_is_created_and_outputs_replace_old_files(recording, tmp_path, capsys):
    (tmp_path / 'a.json').write_text('old')
    code, out, err = run(capsys, 'analyze', recording, '--plots', tmp_path / 'plots', '--json',
                         tmp_path / 'a.json', '--cycles-csv', tmp_path / 'c.csv')
    assert code == 0 and not err, err
    assert (tmp_path / 'a.json').read_text().startswith('{')
    assert listing(tmp_path / 'plots') == ['fig2_twist_cycle.png', 'fig3_speeds_cycle.png',
                                           'timeseries.png']
    assert listing(tmp_path) == ['a.json', 'c.csv', 'plots']
    mode = os.stat(tmp_path / 'c.csv').st_mode & 0o777
    umask = os.umask(0)
    os.umask(umask)
    assert mode == 0o666 & ~umask                         # as open() would have made it


def test_output_files_library(tmp_path):
    source = tmp_path / 'in.mcap'
    source.write_bytes(b'x')
    with pytest.raises(OutputError, match='input'):
        OutputFiles(inputs=[source]).check(source)
    with pytest.raises(OutputError, match='255 bytes'):
        OutputFiles().check(tmp_path / ('n' * 300))
    out = OutputFiles()
    with pytest.raises(RuntimeError), out:
        out.write(tmp_path / 'a.txt', lambda f: f.write('partial'))
        raise RuntimeError('the command failed after writing one output')
    assert listing(tmp_path) == ['in.mcap']
    with OutputFiles() as out:
        assert out.write(tmp_path / 'b.txt', lambda f: f.write('done')) == 4
        assert listing(tmp_path) != ['b.txt', 'in.mcap']          # not before the commit
    assert (tmp_path / 'b.txt').read_text() == 'done'
