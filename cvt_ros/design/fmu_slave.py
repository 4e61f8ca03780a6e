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
"""
import json
import math
from pathlib import Path

from pythonfmu import Fmi2Causality, Fmi2Slave, Fmi2Variability, Integer, Real, String
from pythonfmu.default_experiment import DefaultExperiment
from pythonfmu.enums import Fmi2Status

SCENE_FILE = 'cvt_scene.json'
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
