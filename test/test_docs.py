"""The examples a user copies first run as written: the README's core example and the controller
guide's own controller (docs/controller.md: the module, the command line that runs it, and the
pytest file that tests it — with the offline back end, as the guide's first test uses).
docs/lockstep.md's rclpy controller is run against cvt_node by test_node_lockstep.py."""
import os
import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def python_blocks(name):
    return re.findall(r'^```python\n(.*?)^```', (ROOT / name).read_text(), re.S | re.M)


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
    command = [sys.executable, '-m', 'cvt_ros', 'scenario', 'run', 'conveyor_load_step',
               '--controller', 'my_pkg.pi:make', '--duration', '6', '--quiet',
               '--json', str(tmp_path / 'run.json')]
    proc = subprocess.run(command, cwd=tmp_path, capture_output=True, text=True, timeout=600,
                          env={**os.environ, 'PYTHONPATH': str(tmp_path)})
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert '"settling_time"' in (tmp_path / 'run.json').read_text()
    # the guide's pytest file, its offline test (the dds one is the kit's own tests' business)
    first_test = test_file.split('\n\n\n@pytest.mark')[0]
    (tmp_path / 'test_my_pi.py').write_text(first_test)
    proc = subprocess.run([sys.executable, '-m', 'pytest', '-q', '-p', 'no:cacheprovider',
                           'test_my_pi.py'], cwd=tmp_path, capture_output=True, text=True,
                          timeout=600, env={**os.environ, 'PYTHONPATH': str(tmp_path)})
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert '1 passed' in proc.stdout
