"""The real ROS 2 command line against cvt_node (issue 13): what a ROS user types, checked.

One node for the module, started as a user starts it (``ros2 run cvt_ros cvt_node``: realtime,
100 Hz, so that ``topic echo``/``hz`` have a stream and the machine is spared), and a ``ros2``
daemon on the module's own domain, so that every command sees the same discovered graph. Nothing
waits by sleeping: the set-up waits until ``ros2 node info`` shows the whole interface, commands
wait for their peers (``topic pub -w``, ``service call``, ``param --timeout``), effects are waited
for in the node's log and diagnostics. Independent commands run side by side (each ``ros2``
costs 1-2 s to start).

The ``ros2`` command comes from the vendored upstream ros2cli (0.32.2) that ./run.sh installs
into the venv when ``../shared/vendor/ros2cli`` (or ``$CVT_ROS2CLI_VENDOR``) exists; without it
this module is skipped with that reason.
"""
import math
import re
import signal
import subprocess
import sys
import threading
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest
import yaml
from diagnostic_msgs.msg import DiagnosticArray
from node_harness import (
    RELIABLE,
    NodeProcess,
    Probe,
    diagnostics_values,
    domain_id,
    ros_env,
    wait_for,
)

from cvt_ros.parameters import SPECS

ROS2 = Path(sys.prefix) / 'bin' / 'ros2'
if not ROS2.exists():
    pytest.skip(f"no ros2 command in {ROS2.parent}: ./run.sh installs the vendored ros2cli "
                f"when ../shared/vendor/ros2cli (or $CVT_ROS2CLI_VENDOR) exists",
                allow_module_level=True)

NODE = '/cvt_sim'
TIMEOUT = 120.0      # [s] for one ros2 command (they wait for their peers); a hang, not a pace
SIDE_BY_SIDE = 4    # ros2 commands at once
ATTEMPTS = 3        # for a ros2 param verb whose participant missed the node's services
DBL_MAX_TEXT = '1.7976931348623157e+308'
DDS_LOG = re.compile(r'(\x1b\[[\d;]*m)*\d{4}-\d\d-\d\d \d\d:\d\d:\d\d\.\d+ ')   # Fast DDS's log
INTERFACE = {        # what `ros2 node info` must list: the node's whole interface
    'Subscribers': ['/crank_length_cmd: std_msgs/msg/Float64',
                    '/load_torque_cmd: std_msgs/msg/Float64',
                    '/joint_commands: sensor_msgs/msg/JointState'],
    'Publishers': ['/joint_states: sensor_msgs/msg/JointState',
                   '/state: sensor_msgs/msg/JointState',
                   '/clutch_engaged: std_msgs/msg/Bool',
                   '/clock: rosgraph_msgs/msg/Clock',
                   '/diagnostics: diagnostic_msgs/msg/DiagnosticArray'],
    'Service Servers': ['/cvt_sim/reset: std_srvs/srv/Trigger',
                        '/cvt_sim/pause: std_srvs/srv/SetBool',
                        '/cvt_sim/step: std_srvs/srv/Trigger',
                        '/cvt_sim/set_parameters: rcl_interfaces/srv/SetParameters'],
}
JOINTS = ['crank', 'rocker', 'clutch_output', 'output_shaft', 'crank_length']


# what a verb prints once it has done its work (the rest of its run is its own shutdown)
ANSWERED = {('topic', 'pub'): ('publishing #1:',),
            ('param', 'set'): ('Set parameter successful', 'Setting parameter failed')}


def _text(output):
    """What a timed-out process wrote (bytes, str or None) as text."""
    if isinstance(output, bytes):
        return output.decode(errors='replace')
    return output or ''


class Ros2:
    """``ros2 ARGS`` in a domain: one at a time (``run``) or side by side (``run_all``)."""

    def __init__(self, domain):
        self.env = ros_env(domain)

    def popen(self, *args):
        return subprocess.Popen([sys.executable, str(ROS2), *args], env=self.env, text=True,
                                stdout=subprocess.PIPE, stderr=subprocess.STDOUT)

    def run(self, *args):
        """One command's output: stdout, then stderr, without Fast DDS's own log lines (a busy
        machine's shared-memory port files: `RTPS_TRANSPORT_SHM Error ...`, DDS falls back to
        UDP). The `ros2 param` verbs give a new DDS participant a fixed 5 s to discover the
        node's parameter services (upstream); when they did not, nothing was set or read, and
        the command is asked again. A command that gave its answer and then did not exit
        (the CLI hung in its own DDS shutdown: `ros2 topic pub` after its keep-alive in CI's
        loaded run; a `ros2 param set` timed out once at load 5) is stopped at the timeout and
        counts as done: what the node did is what the tests check; one that hung before any
        answer is asked again."""
        output = None
        for _ in range(ATTEMPTS):
            try:
                proc = subprocess.run([sys.executable, str(ROS2), *args], env=self.env,
                                      text=True, capture_output=True, timeout=TIMEOUT)
                stdout, stderr = proc.stdout, proc.stderr
            except subprocess.TimeoutExpired as exc:   # subprocess.run killed it
                stdout, stderr = (_text(exc.stdout), _text(exc.stderr))
                if not stdout.strip():
                    continue
                if not any(answer in stdout for answer in ANSWERED.get(args[:2], ())):
                    raise
            output = ''.join(line for line in (stdout + stderr).splitlines(True)
                             if not DDS_LOG.match(line))
            if 'Wait for service timed out waiting for parameter services' not in output:
                break
        assert output is not None, f"ros2 {' '.join(args)}: no answer in {ATTEMPTS} tries"
        return output

    def run_all(self, *commands):
        """Run the commands side by side (a few at a time: a loaded 2-core machine still
        schedules each); their outputs, in order."""
        with ThreadPoolExecutor(max_workers=SIDE_BY_SIDE) as pool:
            return list(pool.map(lambda c: self.run(*c), commands))

    def quiet(self, *args):
        """A command whose output does not matter (the daemon keeps no pipe of ours open)."""
        return subprocess.run([sys.executable, str(ROS2), *args], env=self.env, timeout=TIMEOUT,
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL).returncode


class Cli:
    """The module's node (through ``ros2 run``), the ros2 runner, and a probe on /diagnostics."""

    def __init__(self, recording):
        self.domain = domain_id()
        self.ros2 = Ros2(self.domain)
        self.ros2.quiet('daemon', 'start')
        self.recording = recording
        self.node = NodeProcess(self.domain, ['-p', 'publish_rate:=100.0',
                                              '-p', f'record.path:={recording}'],
                                command=[sys.executable, str(ROS2), 'run', 'cvt_ros',
                                         'cvt_node'])
        self.probe = Probe(self.domain)
        self.diagnostics = self.probe.subscribe(DiagnosticArray, '/diagnostics', RELIABLE)

    def close(self):
        self.probe.close()
        self.ros2.quiet('daemon', 'stop')
        # `ros2 run` waits for its child; SIGINT goes to the node itself (a terminal's Ctrl-C
        # reaches both through the process group), then ros2 run returns its exit code
        import psutil
        for child in psutil.Process(self.node.proc.pid).children(recursive=True):
            child.send_signal(signal.SIGINT)
        try:
            code = self.node.proc.wait(30.0)
        except subprocess.TimeoutExpired:
            code, _ = self.node.stop(signal.SIGINT, 10.0)
        self.node.__exit__(None, None, None)
        return code

    def log(self):
        return self.node.output()

    def diagnostics_now(self):
        """The key/values of the next diagnostics message (published at ~1 Hz)."""
        n = len(self.diagnostics)
        assert wait_for(lambda: len(self.diagnostics) > n, 30.0), self.log()
        return diagnostics_values(self.diagnostics.last())

    def diagnostics_until(self, predicate):
        """The first diagnostics values (from now on) for which ``predicate`` holds."""
        seen = [len(self.diagnostics)]

        def check():
            for msg in self.diagnostics.messages(seen[0]):
                seen[0] += 1
                values = diagnostics_values(msg)
                if predicate(values):
                    return values
            return None
        values = wait_for(check, 60.0)
        assert values, (self.diagnostics_now(), self.log())
        return values

    def service(self, name, srv_type, request='{}'):
        """``ros2 service call``: (success, message) of the response."""
        return response_of(self.ros2.run('service', 'call', name, srv_type, request))

    def param_get(self, name):
        return self.ros2.run('param', 'get', NODE, name, '--timeout', '60')


def response_of(output):
    m = re.search(r"_Response\(success=(True|False), message=(['\"])(.*)\2\)", output)
    assert m, output
    return m.group(1) == 'True', m.group(3)


@pytest.fixture(scope='module')
def cli(tmp_path_factory):
    session = Cli(tmp_path_factory.mktemp('ros2cli') / 'run.mcap')
    try:
        def interface_complete():
            info = session.ros2.run('node', 'info', NODE)
            return info if all(e in info for es in INTERFACE.values() for e in es) else None
        session.info = wait_for(interface_complete, 180.0, interval=0.2)
        assert session.info, (session.ros2.run('node', 'info', NODE), session.log())
        yield session
    finally:
        code = session.close()
    assert code == 0, session.log()


def test_ros2_run_starts_the_node_and_pkg_lists_its_executables(cli):
    """`ros2 run cvt_ros cvt_node` started the module's node (the editable install is in the
    venv's ament index); a typo in a parameter name stops it with exit 2 and the closest name."""
    typo = Ros2(domain_id())   # a domain of its own: no second /cvt_sim beside the module's
    proc = typo.popen('run', 'cvt_ros', 'cvt_node', '--ros-args', '-p', 'time_mod:=fast')
    executables = cli.ros2.run('pkg', 'executables', 'cvt_ros')
    output = proc.communicate(timeout=TIMEOUT)[0]
    # every console script, the ones cvt_controller.launch.py starts included
    assert {'cvt_ros cvt_node', 'cvt_ros cvt-sim', 'cvt_ros cvt_speed_controller',
            'cvt_ros cvt_linkage_markers'} <= set(executables.splitlines()), executables
    assert proc.returncode == 2, output
    assert 'unknown parameter time_mod (did you mean time_mode?)' in output, output
    assert 'Traceback' not in output, output
    assert 'cvt_sim ready' in cli.log() and 'Traceback' not in cli.log(), cli.log()


def test_node_info_lists_the_whole_interface(cli):
    sections = re.split(r'\n  (\w[\w ]*):\n', '\n' + cli.info)
    listed = dict(zip(sections[1::2], sections[2::2], strict=True))
    for section, entries in INTERFACE.items():
        for entry in entries:
            assert entry in listed[section], (section, entry, cli.info)


def test_interface_show_every_type_of_the_interface(cli):
    types = sorted({e.split(': ')[1] for es in INTERFACE.values() for e in es})
    shown = dict(zip(types, cli.ros2.run_all(*[('interface', 'show', t) for t in types]),
                     strict=True))
    fields = {'std_msgs/msg/Float64': 'float64 data', 'std_msgs/msg/Bool': 'bool data',
              'sensor_msgs/msg/JointState': 'float64[] position',
              'rosgraph_msgs/msg/Clock': 'builtin_interfaces/Time clock',
              'diagnostic_msgs/msg/DiagnosticArray': 'DiagnosticStatus[] status',
              'std_srvs/srv/Trigger': 'string message', 'std_srvs/srv/SetBool': 'bool data',
              'rcl_interfaces/srv/SetParameters': 'Parameter[] parameters'}
    for t in types:
        assert fields[t] in shown[t], (t, shown[t])


def _echoed(output):
    """The message ``ros2 topic echo --once`` printed (YAML; ``.nan`` reads as nan), without
    its notes on samples DDS reported lost before it (a reliable reader joining a stream)."""
    lines = [line for line in output.split('\n---')[0].splitlines()
             if not (line.startswith('A message was lost') or line.startswith('\t'))]
    return yaml.safe_load('\n'.join(lines))


def test_topic_echo_once_on_every_published_topic(cli):
    topics = ['/joint_states', '/state', '/clutch_engaged', '/clock', '/diagnostics']
    out = dict(zip(topics, cli.ros2.run_all(*[('topic', 'echo', '--once', t) for t in topics]),
                   strict=True))
    for topic in ('/joint_states', '/state'):
        msg = _echoed(out[topic])
        assert msg['name'] == JOINTS, out[topic]
        assert len(msg['position']) == len(msg['velocity']) == len(msg['effort']) == 5
        assert msg['position'][4] == 0.04            # the actuator joint: the crank length [m]
        assert math.isnan(msg['effort'][4])          # its force is not modelled
        assert msg['header']['stamp']['sec'] * 10**9 + msg['header']['stamp']['nanosec'] > 0
    assert isinstance(_echoed(out['/clutch_engaged'])['data'], bool), out['/clutch_engaged']
    clock = _echoed(out['/clock'])['clock']
    assert clock['sec'] * 10**9 + clock['nanosec'] > 0, out['/clock']
    status = _echoed(out['/diagnostics'])['status'][0]
    assert status['name'] == '/cvt_sim: transmission', out['/diagnostics']
    values = {kv['key']: kv['value'] for kv in status['values']}
    assert values['time_mode'] == 'realtime' and float(values['sim_time']) > 0, values


def test_topic_hz_reports_the_rate_of_joint_states(cli):
    """`ros2 topic hz` prints a rate (its first report, whatever the machine's pace)."""
    proc = cli.ros2.popen('topic', 'hz', '/joint_states')
    lines = []   # ros_env sets PYTHONUNBUFFERED: lines arrive as ros2 prints them
    reader = threading.Thread(target=lambda: lines.extend(iter(proc.stdout.readline, '')),
                              daemon=True)
    reader.start()
    try:
        report = wait_for(lambda: [i for i, line in enumerate(lines[:-1])
                                   if line.startswith('average rate:')], TIMEOUT)
    finally:
        proc.send_signal(signal.SIGINT)
        proc.wait(TIMEOUT)
        reader.join(TIMEOUT)
    assert report, lines
    rate = float(lines[report[0]].split(':')[1])
    assert math.isfinite(rate) and rate > 0, lines
    assert 'window:' in lines[report[0] + 1], lines


def test_topic_pub_once_on_each_command_topic(cli):
    """Valid commands are taken, NaN and out-of-range ones refused (with value and limit in the
    log), on every command topic; the services report what is in force."""
    before = cli.diagnostics_now()
    pub = ('topic', 'pub', '--once', '-w', '1', '--keep-alive', '1')
    crank, load, joint = '/crank_length_cmd', '/load_torque_cmd', '/joint_commands'
    float64, joint_state = 'std_msgs/msg/Float64', 'sensor_msgs/msg/JointState'
    commands = [(crank, float64, '{data: 0.05}'), (crank, float64, '{data: .nan}'),
                (crank, float64, '{data: 0.2}'), (load, float64, '{data: 12.0}'),
                (load, float64, '{data: .nan}'), (load, float64, '{data: 2000.0}'),
                (joint, joint_state, '{name: [crank_length], position: [.nan]}'),
                (joint, joint_state, '{name: [crank_length], position: [0.3]}'),
                (joint, joint_state, '{name: [crank], position: [0.05]}')]
    # ~/step is refused while the simulation runs (realtime): asked meanwhile
    step = ('service', 'call', '/cvt_sim/step', 'std_srvs/srv/Trigger')
    *_, refused_step = cli.ros2.run_all(*[pub + c for c in commands], step)
    received = int(before['commands_received']) + len(commands)
    after = cli.diagnostics_until(lambda v: int(v['commands_received']) >= received)
    assert int(after['commands_received']) == received, after
    assert int(after['commands_refused']) == int(before['commands_refused']) + 7, after
    assert float(after['crank_length_target_m']) == 0.05, after
    assert float(after['load_torque_Nm']) == 12.0, after
    log = cli.log()
    for refused in ('refused crank_length_cmd = nan m: not a finite number; limit [0, 0.1) m',
                    'refused crank_length_cmd = 0.2 m: outside the Grashof range; limit [0, 0.1)',
                    'refused load_torque_cmd = nan N*m: not a finite number',
                    'refused load_torque_cmd = 2000.0 N*m: beyond the limit',
                    'refused joint_commands crank_length = nan m',
                    'refused joint_commands crank_length = 0.3 m',
                    "no joint 'crank_length'"):
        assert refused in log, (refused, log)
    assert 'keeping the last valid command' in log

    # the services, by ros2 service call: step refused while running; pause, step, resume, reset
    ok, message = response_of(refused_step)
    assert not ok and 'only while paused or in lockstep' in message, message
    ok, message = cli.service('/cvt_sim/pause', 'std_srvs/srv/SetBool', '{data: true}')
    assert ok and '(target 0.05 m)' in message and 'load_torque=12 N*m' in message, message
    cli.ros2.run(*pub, joint, joint_state, '{name: [crank_length], position: [0.06]}')
    cli.diagnostics_until(lambda v: float(v['crank_length_target_m']) == 0.06)
    t_paused = float(re.search(r't=([\d.]+) s', message).group(1))
    ok, message = cli.service('/cvt_sim/step', 'std_srvs/srv/Trigger')
    assert ok and '(target 0.06 m)' in message and 'load_torque=12 N*m' in message, message
    t_step = float(re.search(r't=([\d.]+) s', message).group(1))
    assert round((t_step - t_paused) / 0.01) == 1, (t_paused, t_step)   # one period of 10 ms
    ok, message = cli.service('/cvt_sim/pause', 'std_srvs/srv/SetBool', '{data: false}')
    assert ok and message.startswith('running'), message
    ok, message = cli.service('/cvt_sim/reset', 'std_srvs/srv/Trigger')
    assert ok and 't=0.000000000 s' in message, message
    assert '(target 0.04 m)' in message and 'load_torque=8 N*m' in message, message


def _set(cli, *pairs):
    """`ros2 param set` for each (name, value) side by side; their outputs by name."""
    outputs = cli.ros2.run_all(*[('param', 'set', NODE, n, v, '--timeout', '60')
                                 for n, v in pairs])
    return dict(zip([n for n, _ in pairs], outputs, strict=True))


def test_param_set_takes_valid_values_and_refuses_bad_ones_with_the_reason(cli):
    # every refusal is the node's own text (value, unit, the range that applies); note that
    # `ros2 param set` exits 0 also when the set failed (upstream): read what it prints
    out = _set(cli, ('load.viscous', '0.06'), ('solver.rtol', '1e-8'),   # no dot: YAML text
               ('load.torque', '1e6'), ('real_time_factor', '0'), ('inertia.rocker', '1e-12'),
               ('inertia.motor', 'heavy'), ('linkage.crank_length', '0.15'),
               ('linkage.pivot_distance', '0.05'), ('lod.torque', '1'))
    assert 'Set parameter successful' in out['load.viscous'], out
    assert 'Set parameter successful' in out['solver.rtol'], out
    assert 'load.torque: 1e+06 N*m is outside [-100000, 100000]' in out['load.torque'], out
    assert 'real_time_factor: 0 is outside (0, 1000]' in out['real_time_factor'], out
    assert 'inertia.rocker: 1e-12 kg*m^2 is outside 0 or [1e-09, 1000]' in out['inertia.rocker']
    assert "inertia.motor: expected a number [kg*m^2], got 'heavy'" in out['inertia.motor'], out
    assert 'crank length 0.15 m is outside [0, 0.1) m' in out['linkage.crank_length'], out
    assert 'admits no turning crank' in out['linkage.pivot_distance'], out
    assert 'lod.torque (did you mean load.torque?)' in out['lod.torque'], out
    for name, text in out.items():
        assert 'Traceback' not in text and DBL_MAX_TEXT not in text, (name, text)
    got = cli.ros2.run_all(*[('param', 'get', NODE, n, '--timeout', '60') for n in
                             ('load.viscous', 'solver.rtol', 'load.torque', 'inertia.motor')])
    assert got == ['Double value is: 0.06\n', 'Double value is: 1e-08\n',
                   'Double value is: 8.0\n', 'Double value is: 0.08\n'], got
    _set(cli, ('load.viscous', '0.05'), ('solver.rtol', '2e-06'))


def _described(output):
    """`ros2 param describe` output → {name: its lines}."""
    blocks = re.split(r'^Parameter name: ', output, flags=re.M)[1:]
    return {b.split('\n', 1)[0]: b for b in blocks}


def test_param_describe_says_the_true_limits(cli):
    names = list(SPECS)
    every = _described(cli.ros2.run('param', 'describe', NODE, *names, '--timeout', '60'))
    assert sorted(every) == sorted(names)
    for text in every.values():
        assert DBL_MAX_TEXT not in text and '9223372036854775807' not in text, text
        assert 'Additional constraints: ' in text and 'Description: ' in text, text
    crank = every['linkage.crank_length']
    assert 'Max value: 0.1\n' in crank and 'range: [0, 0.1) (Grashof bound' in crank, crank
    assert 'Min value: 0.0\n' in every['real_time_factor'], every['real_time_factor']
    assert 'range: (0, 1000]' in every['real_time_factor']
    assert 'range: 0 or [1e-09, 1000]' in every['inertia.rocker']
    assert 'Min value' not in every['shaft.stiffness']          # may be .inf: no ROS range
    assert 'range: [1, 1e+09] or .inf' in every['shaft.stiffness']
    assert 'Step: 2' in every['linkage.assembly_mode']
    # the crank's limit follows the geometry: h = 0.15 m makes it b + d + h - 2 max = 0.05 m
    out = _set(cli, ('linkage.pivot_distance', '0.15'))
    assert 'Set parameter successful' in out['linkage.pivot_distance'], out
    crank = _described(cli.ros2.run('param', 'describe', NODE, 'linkage.crank_length',
                                    '--timeout', '60'))['linkage.crank_length']
    assert 'Max value: 0.04999999999999999\n' in crank, crank
    assert 'range: [0, 0.04999999999999999)' in crank, crank
    out = _set(cli, ('linkage.crank_length', '0.06'))   # beyond the new bound
    assert '0.06 m is outside [0, 0.04999999999999999) m' in out['linkage.crank_length'], out
    out = _set(cli, ('linkage.pivot_distance', '0.2'))
    assert 'Set parameter successful' in out['linkage.pivot_distance'], out
    crank = _described(cli.ros2.run('param', 'describe', NODE, 'linkage.crank_length',
                                    '--timeout', '60'))['linkage.crank_length']
    assert 'Max value: 0.1\n' in crank, crank


def _load_lines(output):
    return [line for line in output.splitlines() if line.startswith('Set parameter')]


def test_param_dump_then_load_round_trips(cli, tmp_path):
    """`ros2 param dump` → `ros2 param load`: every parameter of the transmission loads back,
    `.inf` and doubles like 2e-06 included; rclpy's read-only start_type_description_service is
    the one line that fails, and both workarounds of docs/node.md work: leave that line out of
    the file, or start a node with the dump as its params file."""
    assert 'Set parameter successful' in _set(cli, ('shaft.stiffness', '.inf'))['shaft.stiffness']
    dump = cli.ros2.run('param', 'dump', NODE, '--timeout', '60')
    values = yaml.safe_load(dump)[NODE]['ros__parameters']
    assert values['shaft']['stiffness'] == math.inf and values['solver']['rtol'] == 2e-6, dump
    path = tmp_path / 'cvt_sim.yaml'
    path.write_text(dump)
    lines = _load_lines(cli.ros2.run('param', 'load', NODE, str(path), '--timeout', '60'))
    failed = [line for line in lines if not line.endswith(' successful')]
    assert failed == ['Set parameter start_type_description_service failed: Trying to set a '
                      'read-only parameter: start_type_description_service.'], lines
    assert len(lines) == len(SPECS) + 2, lines   # + use_sim_time, start_type_description_service

    # workaround 1 (live): without the read-only line every line loads
    trimmed = tmp_path / 'cvt_sim_params.yaml'
    trimmed.write_text(''.join(line for line in dump.splitlines(keepends=True)
                               if 'start_type_description_service' not in line))
    lines = _load_lines(cli.ros2.run('param', 'load', NODE, str(trimmed), '--timeout', '60'))
    assert lines and all(line.endswith(' successful') for line in lines), lines
    assert yaml.safe_load(cli.ros2.run('param', 'dump', NODE, '--timeout', '60')) == \
        yaml.safe_load(dump)
    # loading record.path with the path in force did not restart (truncate) the recording
    assert cli.log().count('recording to') == 1 and 'cannot record' not in cli.log(), cli.log()

    # workaround 2 (at start): the dump as the params file of a new node (here: lockstep)
    domain = domain_id()
    copy_recording = tmp_path / 'copy.mcap'
    with NodeProcess(domain, ['--params-file', str(path), '-p', 'time_mode:=lockstep',
                              '-p', f'record.path:={copy_recording}']) as copy:
        again = Ros2(domain).run('param', 'dump', NODE, '--no-daemon', '--timeout', '120')
        assert copy.alive(), copy.output()
        copy.stop(signal.SIGINT)
    expected = yaml.safe_load(dump)
    expected[NODE]['ros__parameters']['time_mode'] = 'lockstep'
    expected[NODE]['ros__parameters']['record']['path'] = str(copy_recording)
    assert yaml.safe_load(again) == expected, (again, copy.output())
    _set(cli, ('shaft.stiffness', '1500.0'))
