"""One sample row per output time: the columns of ``cvt-sim run --csv`` plus energy bookkeeping."""
from ..physics import layout as L
from ..physics.compiled import kernel

COLUMNS = (
    't', 'phi1', 'phi2', 'phi3', 'phi4', 'omega1', 'omega2', 'omega3', 'omega4', 'engaged',
    'twist', 'clutch_torque', 'crank_length', 'load_torque',
    # beyond the CSV: bookkeeping for summaries, the node and the energy balance
    'motor_torque', 'shaft_torque', 'energy', 'work_motor', 'work_load', 'work_damping',
    'work_actuator', 'constraint',
)
CSV_COLUMNS = COLUMNS[:14]
COL = {name: i for i, name in enumerate(COLUMNS)}
N_COLUMNS = len(COLUMNS)
# an N-path machine (N ≥ 2) has these per path after COLUMNS, each quantity's N together:
# phi2_1 … phi2_N, omega2_1 …, engaged_1 …, clutch_torque_1 … (phi2, omega2 stay path 1's
# rocker; engaged: any clutch engaged; clutch_torque: what all the clutches pass to J3)
PATH_QUANTITIES = ('phi2', 'omega2', 'engaged', 'clutch_torque')


def path_columns(n_paths, per_path=None):
    """The sample columns of a machine of ``n_paths`` paths: COLUMNS for one, unless
    ``per_path`` (the N-path core run at N = 1 has them)."""
    if not (per_path if per_path is not None else n_paths > 1):
        return COLUMNS
    return COLUMNS + tuple(f"{q}_{k}" for q in PATH_QUANTITIES for k in range(1, n_paths + 1))


def csv_columns(columns):
    """The CSV's columns of samples with ``columns``: CSV_COLUMNS, then the per-path ones."""
    return CSV_COLUMNS + tuple(columns[N_COLUMNS:])


@kernel
def write_sample(row, t, y, mode, aux):
    """Fill one output row from a (projected) state and the RHS auxiliaries at time t [s]."""
    row[0] = t
    row[1] = y[L.PHI1]
    row[2] = y[L.PHI2]
    row[3] = y[L.PHI4] + y[L.TWIST]
    row[4] = y[L.PHI4]
    row[5] = y[L.OMEGA1]
    row[6] = y[L.OMEGA2]
    row[7] = y[L.OMEGA3]
    row[8] = y[L.OMEGA4]
    row[9] = 1.0 if mode == L.ENGAGED else 0.0
    row[10] = y[L.TWIST]
    row[11] = aux[L.AUX_CLUTCH_TORQUE]
    row[12] = aux[L.AUX_CRANK_LENGTH]
    row[13] = aux[L.AUX_LOAD_TORQUE]
    row[14] = aux[L.AUX_MOTOR_TORQUE]
    row[15] = aux[L.AUX_SHAFT_TORQUE]
    row[16] = aux[L.AUX_ENERGY]
    row[17] = y[L.W_MOTOR]
    row[18] = y[L.W_LOAD]
    row[19] = y[L.W_DAMPING]
    row[20] = y[L.W_ACTUATOR]
    row[21] = aux[L.AUX_CONSTRAINT]
