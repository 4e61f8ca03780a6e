"""The object behind the ``cvt_device`` fixture: the device a test runs scenarios against."""
from ..scenario import BACKENDS, load_scenario, run_scenario
from ..scenario.model import Scenario


class DeviceUnderTest:
    """Runs scenarios with a controller on one back end; for ``dds`` it holds a ROS domain of its
    own (machine-wide lease, ``cvt_ros.device.domains``) for as long as it lives.

    ``run(scenario, controller=None, **overrides)``: ``scenario`` a shipped name, a path or a
    Scenario; ``controller`` a callable ``controller(measurement) -> crank length | None``, a
    ``MODULE:FACTORY`` string, or None for the reference controller; ``overrides`` replace
    scenario keys (``duration=5.0``, ``seed=3``, ``sensors={...}``). Returns the ScenarioRun.
    """

    def __init__(self, backend='lockstep', tmp_path=None):
        if backend not in BACKENDS:
            raise ValueError(f"cvt_device back end {backend!r}: one of {', '.join(BACKENDS)}")
        self.backend = backend
        self.tmp_path = tmp_path
        self.lease = None
        self.runs = []
        if backend == 'dds':
            from ..device import domains
            self.lease = domains.acquire()

    @property
    def domain(self):
        """The ROS domain id held for this device (dds back end), else None."""
        return self.lease.domain if self.lease is not None else None

    def run(self, scenario, controller=None, **overrides):
        if not isinstance(scenario, Scenario):
            scenario = load_scenario(scenario, overrides or None)
        elif overrides:
            raise ValueError('overrides need a scenario name or path, not a loaded Scenario')
        options = {'domain': self.lease} if self.backend == 'dds' else {}
        run = run_scenario(scenario, controller, self.backend, **options)
        self.runs.append(run)
        return run

    def close(self):
        if self.lease is not None:
            self.lease.release()
            self.lease = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
