"""Controllers for the sweep tests (importable as MODULE:FACTORY by the case runner)."""


def raising(scenario):
    """A controller that fails half a second into the run."""
    def law(measurement):
        if measurement.t > 0.5:
            raise ZeroDivisionError('gain schedule divided by zero')
        return None
    return law


def crashing(scenario):
    """A controller that takes its whole process down (a segfault in a user's extension, say)
    when the load's viscous coefficient is 0.1 or more; otherwise it keeps the crank."""
    import os

    def law(measurement):
        if scenario.values['load.viscous'] >= 0.1:
            os._exit(3)
        return None
    return law


def broken_factory(scenario):
    """A controller factory that cannot even build its controller."""
    raise RuntimeError('no gains file')
