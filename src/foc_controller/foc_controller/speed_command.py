"""What a robot's axis is told to do with its speed, as a record a compiled loop can follow on its own (issue 54):
a speed to reach at a given rate (a step where the rate is ∞: a speed command; the ramp to zero after a command
timeout; homing's search), or a position loop on the estimated mechanical angle (a position command, the hold, homing's
back-off): ω* = ω_ff + k_θ (θ* − θ̂_m) within ±limit. foc_controller.command_hold and foc_controller.position decide
which (slow events: commands, timeouts, the stop found); ``commanded_speed`` turns it into ω* block by block, in the
controller node (answer: nodes) and in the compiled answer (drive_tools.launch.axis_answer), which then follows a
position command without waiting for the interpreter."""
import math

import numpy as np
from numba import njit

SPEED, POSITION = 0.0, 1.0
MODE, TARGET_RAD_S, RATE_RAD_S2, THETA_REF_RAD, OMEGA_FF_RAD_S, GAIN_PER_S, LIMIT_RAD_S = range(7)
N_FIELDS = 7


def speed_command(target_rad_s, rate_rad_s2=math.inf):
    """Reach ``target_rad_s`` [rad/s] from the speed reference now at ``rate_rad_s2`` [rad/s²] (∞: at once)."""
    return np.array([SPEED, target_rad_s, rate_rad_s2, math.nan, 0.0, 0.0, math.inf])


def position_command(theta_ref_rad, omega_ff_rad_s, gain_per_s, limit_rad_s):
    """The position loop to ``theta_ref_rad`` [rad, the estimated mechanical angle's] with feed-forward
    ``omega_ff_rad_s`` [rad/s], gain ``gain_per_s`` k_θ [1/s], within ±``limit_rad_s`` [rad/s]."""
    return np.array([POSITION, 0.0, math.inf, theta_ref_rad, omega_ff_rad_s, gain_per_s, limit_rad_s])


@njit(cache=True, nogil=True)
def commanded_speed(command, speed_now, theta_m_hat, dt_s):
    """The speed reference ω*_m [rad/s] for the next ``dt_s`` [s] of samples by ``command`` (N_FIELDS), the reference
    being ``speed_now`` [rad/s] and the estimated mechanical angle ``theta_m_hat`` [rad]."""
    if command[MODE] == POSITION:
        limit = command[LIMIT_RAD_S]
        speed = command[OMEGA_FF_RAD_S] + command[GAIN_PER_S] * (command[THETA_REF_RAD] - theta_m_hat)
        return max(-limit, min(limit, speed))
    target, step = command[TARGET_RAD_S], command[RATE_RAD_S2] * dt_s
    if not abs(target - speed_now) > step:
        return target
    return speed_now + math.copysign(step, target - speed_now)
