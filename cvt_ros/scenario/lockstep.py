"""``--backend lockstep``: the device core (``cvt_ros.device.core.Device``, what ``cvt_node`` runs)
in this process, stepped by the harness one control period per controller answer — no DDS, for
pytest and for fast iterations. Same calls in the same order as the offline back end, so the
traces are the same to the bit (test_scenario_backends checks it)."""
from ..device.core import CommandError, Device
from ..solver.simulator import SimulationError
from .plants import plant_switches


class LockstepPlant:
    name = 'lockstep'

    def __init__(self, values, period):
        self.device = Device(values, period)

    def start(self):
        return self.device.present_state().row

    def set_load_torque(self, torque):
        self._command(self.device.command_load_torque, torque)

    def command_crank_length(self, length):
        self._command(self.device.command_crank_length, length)

    @staticmethod
    def _command(method, value):
        try:
            method(value)
        except CommandError as exc:   # the harness keeps commands in range: a refusal is a bug
            raise SimulationError(f"the device refused a command: {exc}") from None

    def step(self):
        period = self.device.advance()
        if period is None:
            raise SimulationError(self.device.fault)
        events = period.events
        if self.device.n_paths > 1:   # (the device's switching instants: their switches)
            events = [s for change in events for s in change.switches]
        return period.row, plant_switches(events, self.device.n_paths)

    def self_check(self):
        """The solver's self-check (Simulator.self_check: possibly missed clutch events)."""
        return self.device.sim.self_check()

    def close(self):
        pass
