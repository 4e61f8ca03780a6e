"""The FMU's model class (pythonfmu): the transmission as an FMI 2.0 Co-Simulation slave.

:func:`cvt_ros.design.fmu.build_fmu` copies this file into the FMU (``resources/``) with the
scene's values (``resources/cvt_scene.json``); the FMU's native library (pythonfmu's) starts
Python, imports this module and calls the class below. It imports cvt_ros only when the FMU is
initialized, from the importing machine's Python (docs/design.md: what that machine needs).

Each ``doStep`` is one communication step of the device: the inputs go to the Simulator as the
node's commands do (``command_crank_length``, ``set_load_torque``), then
``Simulator.advance(step)`` and ``Simulator.sample()`` — at the FMU's default step through
``PeriodStepper`` (one compiled call, bit-identical to those two calls, as the device's lockstep
loop runs them).

Variables (SI units): inputs ``crank_length_cmd`` [m] and ``load_torque_cmd`` [N·m] (until an
importer sets them, they follow the parameters ``linkage.crank_length`` and ``load.torque``);
outputs ``<joint>.angle`` [rad] and ``<joint>.speed`` [rad/s] of the joints crank, rocker,
clutch_output, output_shaft (the node's joint_states), ``crank_length`` [m] (actual),
``clutch_engaged`` (1 engaged, 0 not: a Real, which every importer takes) and ``clutch_torque``
[N·m]; every physics parameter of the scene as a fixed parameter under its dotted name.

pythonfmu's native library (0.6.5 to 0.7.0) has three reference-counting defects that corrupt
the importer's heap; this module works around them (docs/design.md, "pythonfmu's native
library"): see :func:`_return_lent_globals`, :func:`_release_at_exit` and
:func:`_outlive_double_release`.
"""
import atexit
import ctypes
import json
import math
import os
import sys
from pathlib import Path

from pythonfmu import Fmi2Causality, Fmi2Slave, Fmi2Variability, Integer, Real, String
from pythonfmu import __version__ as PYTHONFMU_RELEASE  # the FMU's own copy: its library's
from pythonfmu.default_experiment import DefaultExperiment
from pythonfmu.enums import Fmi2Status

SCENE_FILE = 'cvt_scene.json'
# the pythonfmu releases whose native library has the defects below (a test fails on another)
DEFECTIVE_PYTHONFMU = ('0.6.5', '0.6.6', '0.6.7', '0.6.8', '0.6.9', '0.7.0')
LIBRARY_DEFECTS = PYTHONFMU_RELEASE in DEFECTIVE_PYTHONFMU

JOINTS = ('crank', 'rocker', 'clutch_output', 'output_shaft')   # interface.JOINTS
OUTPUTS = tuple((f'{joint}.angle', f'phi{k}', 'rad') for k, joint in enumerate(JOINTS, 1)) + \
    tuple((f'{joint}.speed', f'omega{k}', 'rad/s') for k, joint in enumerate(JOINTS, 1)) + (
        ('crank_length', 'crank_length', 'm'), ('clutch_engaged', 'engaged', '1 engaged, 0 not'),
        ('clutch_torque', 'clutch_torque', 'N*m'))
INPUTS = (('crank_length_cmd', 'linkage.crank_length', 'm', 'crank-length command'),
          ('load_torque_cmd', 'load.torque', 'N*m', 'load torque (constant part)'))


class CvtTransmission(Fmi2Slave):
    """The pulse CVT (cvt_ros) with the parameters of one scene."""

    author = 'cvt_ros'
    description = ('Mechanical pulse CVT: motor, crank-rocker linkage, one-way clutch, torsion '
                   'shaft, load (cvt_ros, exact hybrid model)')

    def __init__(self, **kwargs):
        super().__init__(**kwargs)
        config = json.loads((Path(self.resources) / SCENE_FILE).read_text(encoding='utf-8'))
        self.scene = config['scene']
        self.step = config['step']
        self.default_experiment = DefaultExperiment(0.0, config['stop_time'], config['step'])
        self.parameters = dict(config['values'])
        if LIBRARY_DEFECTS:
            _release_at_exit(self.resources)
        self.sim = self.stepper = None
        self.row = {name: 0.0 for name, _, _ in OUTPUTS}
        self.inputs = {name: self.parameters[key] for name, key, _, _ in INPUTS}
        self.inputs_set = set()       # inputs an importer has set (the others follow parameters)
        self.applied = {}
        for name, key, unit, text in INPUTS:
            self.register_variable(Real(
                name, causality=Fmi2Causality.input, variability=Fmi2Variability.continuous,
                description=f'{text} [{unit}]', start=self.parameters[key],
                getter=lambda n=name: self.inputs[n], setter=lambda v, n=name: self._input(n, v)))
        for name, _, unit in OUTPUTS:
            self.register_variable(Real(
                name, causality=Fmi2Causality.output, variability=Fmi2Variability.continuous,
                description=f'[{unit}]', getter=lambda n=name: self.row[n]))
        for key, (kind, unit, meaning) in config['parameters'].items():
            variable = {'real': Real, 'integer': Integer, 'string': String}[kind]
            self.register_variable(variable(
                key, causality=Fmi2Causality.parameter, variability=Fmi2Variability.fixed,
                description=f'{meaning} [{unit}]', start=self.parameters[key],
                getter=lambda k=key: self.parameters[k],
                setter=lambda v, k=key: self.parameters.__setitem__(k, v)))

    def _input(self, name, value):
        self.inputs[name] = float(value)
        self.inputs_set.add(name)

    def exit_initialization_mode(self):
        try:
            self._initialize()
        except Exception as exc:   # the importer hears why (a bad parameter names itself)
            self.log(f'{type(exc).__name__}: {exc}', Fmi2Status.error)
            if LIBRARY_DEFECTS:
                _outlive_double_release(self)
            raise

    def _initialize(self):
        from cvt_ros import parameters
        from cvt_ros.solver.fidelity import make_simulator
        from cvt_ros.solver.period import PeriodStepper
        values = parameters.validate(self.parameters)
        for name, key, _, _ in INPUTS:
            if name not in self.inputs_set:
                self.inputs[name] = values[key]
        self.sim = make_simulator(values)
        self.stepper = PeriodStepper(self.sim, self.step)
        self.applied = {'crank_length_cmd': values['linkage.crank_length'],
                        'load_torque_cmd': values['load.torque']}
        self._apply_inputs()
        self._read(self.sim.sample())

    def _apply_inputs(self):
        crank, load = self.inputs['crank_length_cmd'], self.inputs['load_torque_cmd']
        if crank != self.applied['crank_length_cmd']:
            self.sim.command_crank_length(crank)
            self.applied['crank_length_cmd'] = crank
        if load != self.applied['load_torque_cmd']:
            self.sim.set_load_torque(load)
            self.applied['load_torque_cmd'] = load

    def _read(self, sample):
        from cvt_ros.solver.output import COL
        for name, column, _ in OUTPUTS:
            self.row[name] = float(sample[COL[column]])

    def do_step(self, current_time, step_size):
        try:
            self._apply_inputs()
            if math.isclose(step_size, self.step, rel_tol=1e-12, abs_tol=0.0):
                sample = self.stepper.advance()
            else:
                self.sim.advance(step_size)
                sample = self.sim.sample()
            self._read(sample)
        except Exception as exc:   # noqa: BLE001 — the importer hears it through the FMI log
            self.log(f't = {current_time:.9g} s: {type(exc).__name__}: {exc}', Fmi2Status.error)
            return False
        return True


# ---- pythonfmu's native library (0.6.5–0.7.0): its defects, worked around -------------------

_exit_releases = {}   # path → handle of each loaded copy of the FMU's library, released at exit


def _return_lent_globals(namespace, module_globals):
    """The library finds the model class by executing this file a second time, into a fresh
    locals dict (``namespace``), and then Py_DECREFs the module's globals — a reference
    PyModule_GetDict only lent it. One count short, the dict can be freed while the module still
    points at it. Give the reference back, once per such execution. (Code at this level must not
    raise: the library would go on with the exception set.)"""
    if namespace is not module_globals and LIBRARY_DEFECTS:
        ctypes.pythonapi.Py_IncRef(ctypes.py_object(module_globals))


def _release_at_exit(resources):
    """The library keeps its interpreter state in a static ``shared_ptr`` that is released twice
    when the process exits with the library loaded (always: dlclose cannot unload it): by the
    static's destructor (an exit handler) and again by the library's destructor function
    (``pyState = nullptr`` on the destroyed pointer), which then decrements a count inside the
    freed block — glibc aborts later ("corrupted double-linked list"), or not, as the heap lies.
    Released once, earlier, by the library's own ``finalizePythonInterpreter`` (from Python's
    exit, before the process's exit handlers), the pointer is null for both."""
    if not sys.platform.startswith('linux'):
        return        # Windows: DllMain releases it before the DLL's static destructors (untested)
    for path in sorted((Path(resources).parent / 'binaries' / 'linux64').glob('*.so')):
        if str(path) in _exit_releases:
            continue
        try:          # the copy the importer loaded (RTLD_NOLOAD: never a second one)
            library = ctypes.CDLL(str(path), mode=os.RTLD_NOLOAD | os.RTLD_NOW)
        except OSError:
            continue
        if not _exit_releases:
            atexit.register(_release_libraries)
        _exit_releases[str(path)] = library


def _release_libraries():
    for library in _exit_releases.values():
        library.finalizePythonInterpreter()


def _outlive_double_release(slave):
    """When a call raises, the library Py_DECREFs the instance, its class and its log queue, and
    does so again when the importer frees the instance: take one more reference to each first."""
    for obj in (slave, type(slave), slave.log_queue):
        ctypes.pythonapi.Py_IncRef(ctypes.py_object(obj))


_return_lent_globals(locals(), globals())
