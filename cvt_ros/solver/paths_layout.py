"""What the N-path core's arrays hold (issue 33): its event rows (the one-path columns, then the
path), the float and int blocks of a PathsSimulator (paths_simulator.py) that the compiled
period reads (period.py), and the carving of its scratch array. Sized for MAX_PATHS paths, so
that every offset is a constant; a machine of N paths uses the first N of each per-path slot."""
from ..physics import layout as L
from ..physics.paths import MAX_PATHS, N_PATH_AUX, N_PATH_PARAMS
from . import advance_layout as AL
from .output import N_COLUMNS
from .paths_open import N_LOOK_ROWS
from .witness import N_GUARD, N_POLY

E_PATH = AL.N_EVENT_COLUMNS        # the path (0-based) whose clutch switched
N_PATH_EVENT_COLUMNS = E_PATH + 1

MAX_STATE = L.N_STATE + MAX_PATHS
N_PATH_COLUMNS = 4                 # phi2_k, omega2_k, engaged_k, clutch_torque_k
MAX_ROW = N_COLUMNS + N_PATH_COLUMNS * MAX_PATHS

# scratch of one advance_paths call: K (7 rows), y_new, ytmp, dytmp, ycomb; aux0, aux1, auxtmp;
# C, G; the guards at the step's start and end; the open output's states (4), modal
# coordinates and dip stack, the rocker speeds' polynomials and the looks' rows (paths_open.py)
N_PATH_SCRATCH = (11 * MAX_STATE + 3 * N_PATH_AUX + 3 * N_POLY + N_GUARD + 2 * MAX_PATHS
                  + 4 * L.N_OUTPUT + AL.N_MODAL + 6 * AL.DIP_STACK + MAX_PATHS * N_POLY
                  + N_LOOK_ROWS * MAX_PATHS)

# the PathsSimulator's float block
PF_Y = 0
PF_P = PF_Y + MAX_STATE
PF_ACT = PF_P + N_PATH_PARAMS
PF_S = PF_ACT + 4 * L.N_ACT_SEGMENTS
PF_H = PF_S + AL.N_SETTINGS
PF_LEDGER = PF_H + AL.N_PROPOSALS
PF_DY = PF_LEDGER + 1
PF_AUX = PF_DY + MAX_STATE
PF_ROW = PF_AUX + N_PATH_AUX
PF_SCRATCH = PF_ROW + MAX_ROW
PF_SIZE = PF_SCRATCH + N_PATH_SCRATCH
