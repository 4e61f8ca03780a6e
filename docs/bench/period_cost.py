"""Thread CPU time of a 10 s steady-state window, as the node spends it: rk4 one 1 ms control
period per compiled call (PeriodStepper, after 2 s), dopri5 as `cvt-sim run` (0.1 s samples,
streamed, after 2 s). Best of ROUNDS windows; one JSON line (ms per window, load average).

It imports whichever checkout PYTHONPATH names, so two revisions compare in alternating runs:

    for k in 1 2 3; do for rev in /path/to/c1dbe6f .; do
      PYTHONPATH=$rev python docs/bench/period_cost.py 25 paper:rk4 conveyor:rk4 paper:dopri5
    done; done

Every revision since c1dbe6f has the calls it makes (load_scene, Simulator, PeriodStepper).
"""
import json
import os
import sys
import time

from cvt_ros.scene import load_scene
from cvt_ros.solver.period import PeriodStepper
from cvt_ros.solver.simulator import Simulator

WINDOW = 10.0   # [s] simulated per round
WARM = 2.0      # [s] from rest before the first round
PERIOD = 1e-3   # [s] the node's control period


def window_cost(scene, method, rounds):
    """Best thread CPU time [ms] of ``rounds`` windows of WINDOW s."""
    sim = Simulator(dict(load_scene(scene), **{'solver.method': method}))
    if method == 'rk4':
        stepper = PeriodStepper(sim, PERIOD)
        for _ in range(round(WARM / PERIOD)):
            stepper.advance()

        def window():
            for _ in range(round(WINDOW / PERIOD)):
                stepper.advance()
    else:
        sim.run(WARM, 0.1, keep_samples=False)

        def window():
            sim.run(WINDOW, 0.1, keep_samples=False)
    best = float('inf')
    for _ in range(rounds):
        t0 = time.thread_time()
        window()
        best = min(best, time.thread_time() - t0)
    return best * 1e3


def main(argv):
    rounds = int(argv[0]) if argv else 15
    cases = argv[1:] or ['paper:rk4', 'conveyor:rk4', 'paper:dopri5', 'conveyor:dopri5']
    result = {case: round(window_cost(*case.split(':'), rounds), 3) for case in cases}
    result['load'] = round(os.getloadavg()[0], 2)
    print(json.dumps(result))


if __name__ == '__main__':
    main(sys.argv[1:])
