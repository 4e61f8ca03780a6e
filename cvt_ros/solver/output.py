"""One sample row per output time: the columns of ``cvt-sim run --csv`` plus energy bookkeeping."""
from ..physics.compiled import kernel
from ..physics.layout import (
    AUX_CLUTCH_TORQUE,
    AUX_CONSTRAINT,
    AUX_CRANK_LENGTH,
    AUX_ENERGY,
    AUX_LOAD_TORQUE,
    AUX_MOTOR_TORQUE,
    AUX_SHAFT_TORQUE,
    ENGAGED,
    OMEGA1,
    OMEGA2,
    OMEGA3,
    OMEGA4,
    PHI1,
    PHI2,
    PHI4,
    TWIST,
    W_ACTUATOR,
    W_DAMPING,
    W_LOAD,
    W_MOTOR,
)

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


@kernel
def write_sample(row, t, y, mode, aux):
    """Fill one output row from a (projected) state and the RHS auxiliaries at time t [s]."""
    row[0] = t
    row[1] = y[PHI1]
    row[2] = y[PHI2]
    row[3] = y[PHI4] + y[TWIST]
    row[4] = y[PHI4]
    row[5] = y[OMEGA1]
    row[6] = y[OMEGA2]
    row[7] = y[OMEGA3]
    row[8] = y[OMEGA4]
    row[9] = 1.0 if mode == ENGAGED else 0.0
    row[10] = y[TWIST]
    row[11] = aux[AUX_CLUTCH_TORQUE]
    row[12] = aux[AUX_CRANK_LENGTH]
    row[13] = aux[AUX_LOAD_TORQUE]
    row[14] = aux[AUX_MOTOR_TORQUE]
    row[15] = aux[AUX_SHAFT_TORQUE]
    row[16] = aux[AUX_ENERGY]
    row[17] = y[W_MOTOR]
    row[18] = y[W_LOAD]
    row[19] = y[W_DAMPING]
    row[20] = y[W_ACTUATOR]
    row[21] = aux[AUX_CONSTRAINT]
