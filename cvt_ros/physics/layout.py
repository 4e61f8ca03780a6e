"""Array layouts shared by the physics kernels and the solver.

The compiled kernels take plain float arrays; these module-level integer constants name their slots
(numba folds them into the machine code as literals).

State vector ``y`` (both formulations use the same layout, SI units)::

    0 PHI1   crank angle φ1 [rad]            1 OMEGA1  crank speed ω1 [rad/s]
    2 PHI2   rocker angle φ2 [rad]           3 OMEGA2  rocker speed ω2 [rad/s]
    4 TWIST  torsion twist θ = φ3 − φ4 [rad] 5 OMEGA3  clutch driven part speed ω3 [rad/s]
    6 PHI4   output angle φ4 [rad]           7 OMEGA4  output speed ω4 [rad/s]
    8..11    work quadratures [J]: motor, load, shaft damping, crank actuator

The twist, not φ3, is a state: φ3 − φ4 is a small difference of two large, ever-growing angles and
would lose digits over hours of simulated time. φ3 = φ4 + θ is reconstructed on output.
"""
import numpy as np

# --- state -------------------------------------------------------------------------------------
PHI1 = 0
OMEGA1 = 1
PHI2 = 2
OMEGA2 = 3
TWIST = 4
OMEGA3 = 5
PHI4 = 6
OMEGA4 = 7
W_MOTOR = 8
W_LOAD = 9
W_DAMPING = 10
W_ACTUATOR = 11
N_STATE = 12
N_DYNAMIC = 8  # states that take part in error control (the work quadratures do not)

# --- the disengaged output subsystem z = y[OUTPUT_STATES], integrated on its own clock --------
OUTPUT_STATES = np.array((TWIST, OMEGA3, PHI4, OMEGA4, W_LOAD, W_DAMPING))
Z_TWIST = 0
Z_OMEGA3 = 1
Z_PHI4 = 2
Z_OMEGA4 = 3
Z_W_LOAD = 4
Z_W_DAMPING = 5
N_OUTPUT = 6
N_OUTPUT_DYNAMIC = 4
# error-controlled while the output subsystem runs on its own clock
INPUT_DYNAMIC = np.array((PHI1, OMEGA1, PHI2, OMEGA2))

# --- clutch modes ------------------------------------------------------------------------------
DISENGAGED = 0
ENGAGED = 1

# --- parameter vector P ------------------------------------------------------------------------
P_A = 0           # crank length a [m] (initial / current command; the actuator gives a(t))
P_B = 1           # rocker length b [m]
P_D = 2           # coupler length d [m]
P_H = 3           # pivot distance h [m]
P_SIGMA = 4       # assembly mode σ = ±1
P_J1 = 5          # inertias [kg·m²]
P_J2 = 6
P_J3 = 7
P_J4 = 8
P_C = 9           # shaft stiffness c [N·m/rad]; inf = rigid shaft
P_KD = 10         # shaft damping [N·m·s/rad]
P_MOTOR_MODEL = 11
P_MOTOR_TORQUE = 12
P_MOTOR_SPEED = 13
P_W0 = 14         # synchronous speed ω0 [rad/s]
P_MK = 15         # breakdown torque Mk [N·m]
P_SK = 16         # breakdown slip sk [-]
P_LOAD_TORQUE = 17
P_LOAD_VISCOUS = 18
P_LOAD_QUADRATIC = 19
P_RELEASE = 20
P_FORMULATION = 21
P_RIGID = 22      # 1.0 when c = inf (J3 and J4 lumped, θ ≡ 0)
P_BAUMGARTE = 23  # constraint stabilization rate for the paper formulation [1/s]
P_TORQUE_SCALE = 24  # a torque typical of the scene [N·m], sets the clutch torque event tolerance
P_LINEAR_OUTPUT = 25  # 1.0: the disengaged output subsystem is linear and solved exactly
P_OUTPUT_RATE = 26    # its fastest rate max|λ| [1/s]
P_OUTPUT_RING = 27    # its fastest oscillation max|Im λ| [1/s]: how densely the slip is watched
N_PARAMS = 28

MOTOR_INDUCTION = 0
MOTOR_CONSTANT_TORQUE = 1
MOTOR_CONSTANT_SPEED = 2

RELEASE_TORQUE = 0
RELEASE_TWIST = 1

FORMULATION_REDUCED = 0
FORMULATION_PAPER = 1

# --- auxiliary outputs of the right-hand side --------------------------------------------------
AUX_ROCKER_SPEED = 0      # v = u·ω1 + g_a·a'  [rad/s]
AUX_ROCKER_ACCEL = 1      # v' [rad/s²]
AUX_CLUTCH_TORQUE = 2     # Tc [N·m] (0 when disengaged)
AUX_MOTOR_TORQUE = 3      # M1 [N·m]
AUX_LOAD_TORQUE = 4       # M4 [N·m]
AUX_SHAFT_TORQUE = 5      # c·θ + k·(ω3 − ω4) [N·m]
AUX_SLIP = 6              # s = ω3 − v [rad/s]
AUX_SLIP_RATE = 7         # s' [rad/s²]
AUX_CONSTRAINT = 8        # f(φ1, φ2, a) [m²] (paper formulation drift; 0 in reduced)
AUX_CRANK_LENGTH = 9      # a(t) [m]
AUX_ACTUATOR_POWER = 10   # power the crank actuator puts in [W]
AUX_ENERGY = 11           # T + Π [J]
AUX_FREE_SLIP_RATE = 12   # = AUX_SLIP_RATE (the twist rule read it once; now Tc: clutch.py)
N_AUX = 13

# --- crank actuator profile: rows of (t_start, a0, a'0, a'') -----------------------------------
ACT_T = 0
ACT_A = 1
ACT_V = 2
ACT_ACC = 3
N_ACT_SEGMENTS = 5
