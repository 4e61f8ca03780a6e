"""Design a controller from the device: plant models at operating points (python-control), a gain
schedule on the Dask sweep engine, PI tuning checked on the full device, an FMI 2.0 FMU.

    from cvt_ros.design.identify import identify
    plant = identify('conveyor')                   # steps + sine sweeps at the steady state
    plant.tf('crank_length')                       # control.TransferFunction, rad/s per m

Rooms inside: operating_point.py (the steady state, or why there is none) → experiment.py
(driving the Simulator's inputs, cycle means) → fit.py (FOPDT / second-order fits as
python-control objects) and frequency.py (sine sweeps, cycle-mean demodulation) → identify.py
(both inputs, both outputs, JSON) → schedule.py (a grid of operating points on the sweep
engine), tune.py (SIMC PI, checked with the controller kit), fmu.py + fmu_slave.py (the FMU);
plots.py draws, outputs.py writes. The design tools sit above solver/, scenario/ and sweep/.
"""
from .errors import DesignError

__all__ = ['DesignError']
