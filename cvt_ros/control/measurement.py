"""What a controller sees each control period, and what it answers.

A controller is any callable ``controller(measurement) -> crank_length_command`` (metres, or None
to keep the last command), optionally with a ``reset()`` method. It is called once per control
period with the controller-facing state of the device: the joint states (after the scenario's
sensor model: noise, quantization, delay, decimation), the actuator's measured crank length and
the set point of the scenario's schedule. No rclpy here: the same control law runs offline,
in-process in lockstep, and inside a ROS node.
"""
from typing import NamedTuple

#: joint order of position / velocity / effort (as in joint_states): J1..J4
JOINTS = ('crank', 'rocker', 'clutch_output', 'output_shaft')


class Measurement(NamedTuple):
    """The controller-facing state at one control period (SI units, REP-103 signs)."""
    t: float                 # simulation time of the sample [s]
    position: tuple          # φ1..φ4 [rad], JOINTS order
    velocity: tuple          # ω1..ω4 [rad/s]
    effort: tuple            # motor torque, clutch torque, shaft torque, load torque [N·m]
    crank_length: float      # the actuator's crank length a [m] (its state, not the command)
    clutch_engaged: bool     # the clutch transmits torque at the sample (effort[1] > 0)
    setpoint: float          # output speed set point ω4* [rad/s] of the scenario schedule

    @property
    def crank_angle(self):
        return self.position[0]

    @property
    def output_angle(self):
        return self.position[3]

    @property
    def output_speed(self):
        return self.velocity[3]


class ControllerError(RuntimeError):
    """A controller that raised or answered something that is not a crank length."""
