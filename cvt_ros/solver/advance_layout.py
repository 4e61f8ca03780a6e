"""What ``hybrid.advance``'s arrays hold: its settings, counters, status codes, event rows, the
step-size proposals it carries between calls and the carving of its one scratch array.

The solver's callers (simulator.py, period.py, the benchmarks) read and fill these arrays by the
names here; the compiled pieces of the loop (dense_step.py, guard_watch.py,
slip_watch.py, hybrid.py) share them.
"""
from ..physics.layout import N_AUX, N_OUTPUT, N_STATE
from .witness import N_GUARD, N_POLY

# settings vector S
S_METHOD = 0
S_RTOL = 1
S_ATOL = 2
S_H_FIXED = 3
S_MAX_STEP = 4
S_STEP_BUDGET = 5   # steps one call may take before it gives up (no-progress watchdog)
N_SETTINGS = 6

# counters (int64)
C_STEPS = 0
C_REJECTED = 1
C_NEXT_SAMPLE = 2
C_EVENTS = 3
C_STATUS = 4
C_SWITCHES = 5
C_SUBSTEPS = 6
C_ENGAGED_STEPS = 7
C_RHS = 8          # right-hand-side evaluations (every one, in any mode)
C_LATE = 9         # guards found beyond their band after a step: possibly missed events
N_COUNTERS = 10

DIP_STACK = 24   # pieces slip_look.split_dip may hold at once
N_MODAL = 2 * 3 * 2   # the modal coordinates W, complex (2, 3), as float64s
# the working arrays of one advance call, carved out of one float64 array (``scratch``) in
# this order: K, y_new, ytmp, dytmp, ycomb; aux0, aux1, auxtmp; Ko, z, z_new, ztmp, zs; C, G;
# W; the dip stack
N_SCRATCH = (11 * N_STATE + 3 * N_AUX + 11 * N_OUTPUT + 3 * N_POLY + N_GUARD + N_MODAL
             + 6 * DIP_STACK)

STATUS_OK = 0
STATUS_EVENTS_FULL = 1
STATUS_STEP_TOO_SMALL = 2
STATUS_NONFINITE = 3
STATUS_ZENO = 4  # events without the time moving on: the automaton would loop
STATUS_NO_PROGRESS = 5  # the step budget of one call is spent

# events table columns
E_T = 0
E_MODE = 1
E_KIND = 2
E_VALUE = 3
E_LATE = 4   # 1.0: switched because the guard was found beyond its band (possibly missed)
N_EVENT_COLUMNS = 5

# step-size proposals h_io carried between calls
H_MAIN = 0
H_OUTPUT = 1       # the open output's own clock
H_RESTART = 2      # + mode: cap of the first step after a switch into that mode (≤ 0: none yet)
N_PROPOSALS = 4

# what the watch over an accepted step found (returned by the kernels, not stored)
NO_EVENT = 0
CROSSING = 1      # a crossing or a dip of the guard, located
FOUND_LATE = 2    # the guard found beyond its band after the step: switched at once (C_LATE)
