"""The device as the harness sees it: a plant stepped one control period at a time.

Every back end offers the same five calls, so the harness loop (harness.py) is one piece of code:

* ``start()`` → the sample row at t = 0 (``cvt_ros.solver.output.COLUMNS``);
* ``set_load_torque(m)`` and ``command_crank_length(a)``: take effect at the next period;
* ``step()`` → (sample row at the end of the period, clutch switches inside it as (t, engaged);
  N ≥ 2 paths: (t, engaged, path), each clutch's); the row may be the plant's own buffer,
  rewritten by the next ``step()``;
* ``close()``.

``OfflinePlant`` drives the core's Simulator directly: commands, then ``advance(period)`` and
``sample()`` in one compiled call (``solver.period.PeriodStepper``, to the bit) — the same calls,
in the same order, as the device's lockstep loop makes, which is why the two give bit-identical
traces.
"""
from ..solver.fidelity import make_simulator
from ..solver.period import NO_SWITCHES, PeriodStepper


def plant_values(scenario):
    """The scene values every back end builds its device from: the scenario's scene with the load
    schedule's initial value as the load torque."""
    return dict(scenario.values, **{'load.torque': scenario.load.initial})


def plant_switches(switches, n_paths):
    """The core's ClutchSwitch list as a plant reports it: (t, engaged) for one path, (t,
    engaged, path) for N ≥ 2 (grazing contacts left out)."""
    if n_paths > 1:
        return [(s.t, s.engaged, s.path) for s in switches if s.kind != 'graze']
    return [(s.t, s.engaged) for s in switches if s.kind != 'graze']


class OfflinePlant:
    """The core's Simulator, no device around it (``--backend offline``)."""
    name = 'offline'

    def __init__(self, values, period):
        self.sim = make_simulator(values)
        self.stepper = PeriodStepper(self.sim, period)
        self.period = period

    def start(self):
        return self.sim.sample()

    def set_load_torque(self, torque):
        self.sim.set_load_torque(torque)

    def command_crank_length(self, length):
        self.sim.command_crank_length(length)   # (the stepper reads the new profile)

    def step(self):
        row = self.stepper.advance()   # the stepper's buffer: the harness copies it at once
        switches = self.stepper.switches
        if not switches:
            return row, NO_SWITCHES
        return row, plant_switches(switches, self.sim.n_paths)

    def self_check(self):
        """The solver's self-check (Simulator.self_check: possibly missed clutch events)."""
        return self.sim.self_check()

    def close(self):
        pass
