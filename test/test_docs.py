"""The docs' examples run as written.

Every ```bash block of README.md and docs/*.md runs, from a fresh shell (the user's PATH without
the venv, no AMENT_PREFIX_PATH: what a new terminal has) in the checkout, line after line as bash
runs a script, and must end with exit code 0. A block that cannot run here says so on its first
line: ``# not run by the tests: <why>`` (a full ROS install, a cluster of machines). A block may
start servers in the background (``cvt_node ... &``): when its last command has returned they get
SIGINT, as Ctrl-C gives them, and must exit 0 too. The blocks run in a scratch copy of the
checkout (links to its files: the outputs land there, not in the repository), one per docs page,
with the files the pages tell the reader to write first (docs/controller.md's my_pkg/pi.py).
DDS traffic stays on this host on a ROS domain leased for the test.

Besides: the README's core example (Python), and the controller guide's own controller — the
module, the command line that runs it, the pytest file that tests it — and its table, which is
what the command above it prints. docs/lockstep.md's rclpy controller is run against cvt_node by
test_node_lockstep.py.
"""
import os
import re
import signal
import subprocess
import sys
import tempfile
from pathlib import Path

import pytest

from cvt_ros.device import domains

ROOT = Path(__file__).resolve().parent.parent
PAGES = ['README.md'] + sorted(str(p.relative_to(ROOT)) for p in (ROOT / 'docs').glob('*.md'))
NOT_RUN = '# not run by the tests:'
BLOCK_TIMEOUT = 300   # s: a block that hangs (a server that never answers) fails, not the suite


def blocks(name, language):
    """(line number, text) of every ```language block of a page."""
    text = (ROOT / name).read_text()
    return [(text[:m.start()].count('\n') + 1, m.group(1)) for m in
            re.finditer(rf'^```{language}\n(.*?)^```', text, re.S | re.M)]


def python_blocks(name):
    return [body for _, body in blocks(name, 'python')]


COMMAND_BLOCKS = [(page, line, body) for page in PAGES for line, body in blocks(page, 'bash')]


def fresh_environment(domain):
    """A new terminal's environment: no venv on PATH, no ROS set-up, this test's own domain."""
    venv_bin = str(Path(sys.executable).parent)
    keep = ('HOME', 'USER', 'LANG', 'LC_ALL', 'TMPDIR', 'TERM',
            # the checkout's code (a worktree sharing another checkout's venv) and kernel cache
            'PYTHONPATH', 'NUMBA_CACHE_DIR')
    env = {k: os.environ[k] for k in keep if k in os.environ}
    env['PATH'] = os.pathsep.join(p for p in os.environ.get('PATH', '/usr/bin:/bin').split(
        os.pathsep) if p and Path(p).resolve() != Path(venv_bin).resolve()
        and not p.startswith(str(ROOT)))
    env.update(ROS_DOMAIN_ID=str(domain), ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST',
               MPLBACKEND='Agg')
    return env


@pytest.fixture(scope='module')
def domain():
    """A ROS domain of the test's own, with a ros2 daemon for it (`ros2 node`, `ros2 param`
    start one on first use that outlives the block: started here, it is stopped here)."""
    with domains.acquire() as lease:
        env = fresh_environment(lease.domain)
        ros2 = [sys.executable, str(Path(sys.executable).parent / 'ros2'), 'daemon']
        daemon = Path(sys.executable).parent.joinpath('ros2').exists()
        if daemon:
            subprocess.run(ros2 + ['start'], env=dict(env, AMENT_PREFIX_PATH=sys.prefix),
                           stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, timeout=120)
        try:
            yield lease
        finally:
            if daemon:
                subprocess.run(ros2 + ['stop'], env=dict(env, AMENT_PREFIX_PATH=sys.prefix),
                               stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, timeout=120)


@pytest.fixture(scope='module')
def checkouts(tmp_path_factory):
    """One scratch copy of the checkout per page: links to the repository's top-level entries,
    with the files the guide has the reader write."""
    made = {}

    def checkout(page):
        if page not in made:
            path = tmp_path_factory.mktemp(Path(page).stem)
            for entry in ROOT.iterdir():
                if entry.name not in ('.git',) and not entry.name.startswith('.pytest'):
                    (path / entry.name).symlink_to(entry)
            module = python_blocks('docs/controller.md')[0]
            (path / 'my_pkg').mkdir()
            (path / 'my_pkg' / '__init__.py').write_text('')
            (path / 'my_pkg' / 'pi.py').write_text(module)
            made[page] = path
        return made[page]
    return checkout


def _stop_session(sid):
    """SIGKILL whatever the block left running in its session (a block that failed midway)."""
    for stat in Path('/proc').glob('[0-9]*/stat'):
        try:
            fields = stat.read_text().rsplit(')', 1)[1].split()
            if int(fields[3]) == sid:
                os.kill(int(stat.parent.name), signal.SIGKILL)
        except (OSError, ValueError, IndexError):
            pass


def run_block(body, cwd, env):
    # job control (set -m) as in a terminal: background jobs take SIGINT; once the block's last
    # command returned, each job still running gets SIGINT (its process group: Ctrl-C's) and
    # must exit 0
    script = ('set -m\nset -eo pipefail\n' + body
              + '\njobs=$(jobs -pr)'
              + '\nfor job in $jobs; do kill -INT -- "-$job" 2>/dev/null || true; done'
              + '\nfor job in $jobs; do wait "$job"; done\n')
    # (output to a file, not a pipe: a process the block leaves behind would hold a pipe open)
    with tempfile.TemporaryFile('w+') as log:
        proc = subprocess.Popen(['bash', '-c', script], cwd=cwd, env=env, text=True, stdout=log,
                                stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                                start_new_session=True)
        try:
            code = proc.wait(timeout=BLOCK_TIMEOUT)
        except subprocess.TimeoutExpired:
            code = -1
        finally:
            _stop_session(proc.pid)
            proc.wait()
        log.seek(0)
        return code, log.read()


@pytest.mark.parametrize('page, line, body', COMMAND_BLOCKS,
                         ids=[f'{p}:{n}' for p, n, _ in COMMAND_BLOCKS])
def test_command_block_runs_as_written(page, line, body, checkouts, domain):
    first = body.splitlines()[0] if body.strip() else ''
    if first.startswith(NOT_RUN):
        assert first[len(NOT_RUN):].strip(), f'{page}:{line}: say why it is not run'
        pytest.skip(f'{page}:{line}: {first[len(NOT_RUN):].strip()}')
    code, out = run_block(body, checkouts(page), fresh_environment(domain.domain))
    assert code == 0, (f'{page}:{line} exited {code}:\n{body}\n--- output:\n'
                       + (out if len(out) < 6000 else out[:3000] + '\n[…]\n' + out[-3000:]))
    for table in tables_after(page, line):
        assert table in out, (f'{page}:{line}: the table the page shows after this block is not '
                              f'what it prints:\n{table}\n--- printed:\n{out[-4000:]}')


def tables_after(page, line):
    """A markdown table the page introduces as this block's output ("The table printed …",
    right after the block)."""
    text = (ROOT / page).read_text()
    rest = text.split('\n')[line:]
    end = next(i for i, s in enumerate(rest) if s.startswith('```'))
    after = '\n'.join(rest[end + 1:end + 40])
    m = re.match(r'\s*\n[^\n]*table printed[^\n]*\n(?:[^\n]*\n)*?\n((?:\|[^\n]*\n)+)', after)
    return [m.group(1).rstrip('\n')] if m else []


def test_every_command_block_is_bash():
    """Shell examples are ```bash blocks (the ones the test runs): no ```sh, ```shell, ```console
    that would escape it."""
    other = [(page, line) for page in PAGES for language in ('sh', 'shell', 'console', 'zsh')
             for line, _ in blocks(page, language)]
    assert not other, other


def test_readme_core_example_runs():
    (block,) = python_blocks('README.md')
    namespace = {}
    exec(compile(block, 'README.md', 'exec'), namespace)   # noqa: S102 — the doc's own code
    result = namespace['result']
    assert result.samples[-1, 0] == namespace['sim'].t and len(result.samples) == 5001


def test_controller_guide_example_runs_from_the_command_line_and_in_pytest(tmp_path):
    module, test_file = python_blocks('docs/controller.md')[:2]
    package = tmp_path / 'my_pkg'
    package.mkdir()
    (package / '__init__.py').write_text('')
    (package / 'pi.py').write_text(module)
    paths = os.pathsep.join([str(tmp_path)] + [p for p in os.environ.get('PYTHONPATH', '').split(
        os.pathsep) if p])
    command = [sys.executable, '-m', 'cvt_ros', 'scenario', 'run', 'conveyor_load_step',
               '--controller', 'my_pkg.pi:make', '--duration', '6', '--quiet',
               '--json', str(tmp_path / 'run.json')]
    proc = subprocess.run(command, cwd=tmp_path, capture_output=True, text=True, timeout=600,
                          env={**os.environ, 'PYTHONPATH': paths})
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert '"settling_time"' in (tmp_path / 'run.json').read_text()
    # the guide's pytest file, its offline test (the dds one is the kit's own tests' business)
    first_test = test_file.split('\n\n\n@pytest.mark')[0]
    (tmp_path / 'test_my_pi.py').write_text(first_test)
    proc = subprocess.run([sys.executable, '-m', 'pytest', '-q', '-p', 'no:cacheprovider',
                           'test_my_pi.py'], cwd=tmp_path, capture_output=True, text=True,
                          timeout=600, env={**os.environ, 'PYTHONPATH': paths})
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert '1 passed' in proc.stdout


def test_controller_guide_scenario_file_loads_and_runs(tmp_path):
    """The guide's scenario file, every key, with the profile it names: shipped next to the
    scenarios (config/scenarios/belt_load.csv), where a file in that folder finds it."""
    from cvt_ros.scenario import load_scenario, run_scenario
    text = (ROOT / 'docs' / 'controller.md').read_text()
    (body,) = [b for _, b in blocks('docs/controller.md', 'yaml') if 'profile:' in b]
    shipped = ROOT / 'config' / 'scenarios' / 'belt_load.csv'
    assert shipped.is_file() and 'belt_load.csv' in text
    (tmp_path / 'belt_load.csv').symlink_to(shipped)
    (tmp_path / 'example.yaml').write_text(body)
    scenario = load_scenario(tmp_path / 'example.yaml')
    run = run_scenario(scenario)
    assert run.ok, run.error
    assert len(run.steps) == 1 + 2 + 3   # the start, two set-point and three load changes
