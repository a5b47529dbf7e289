"""The kernels the host's answer through the bridge runs around the cores' block kernels, in Python
(bridge_loop) and compiled whole (compiled_answer): a telemetry block into the drive's inputs, the commands
into the delay line and the samples into log rows."""
import math

from numba import njit

from drive_common.math.command_delay import issue_command

from .loop import write_row

NO_TRUTH = (0.0,) * 7
"""The plant's truth in a log row the host writes: it knows none (the inverter's truth fills it after the run)."""


@njit(cache=True)
def fill_inputs(inputs, currents, theta_m, n_p, speed_ref, tau_feedforward, k0, n):
    """Samples k0 … k0 + n − 1 of a telemetry block into ``inputs`` (DRIVE_INPUT records): the measured
    ``currents`` (n × 3) [A], the encoder's mechanical ``theta_m`` [rad] as electrical (NaN: none, 0) and
    the schedule's speed reference [rad/s] and torque feed-forward [N·m] of each sample (arrays of one: the
    live value, for every sample)."""
    last = len(speed_ref) - 1
    for i in range(n):
        s = inputs[i]
        s.i_a_A, s.i_b_A, s.i_c_A = currents[i, 0], currents[i, 1], currents[i, 2]
        s.theta_e_encoder_rad = 0.0 if math.isnan(theta_m[i]) else n_p * theta_m[i]
        s.omega_e_encoder_rad_s = 0.0
        s.omega_m_ref_rad_s, s.tau_feedforward_Nm = speed_ref[min(k0 + i, last)], tau_feedforward[min(k0 + i, last)]


@njit(cache=True)
def issue_and_log(line, rows, k0, n, T_s, inputs, estimates, commands):
    """The commands of samples k0 … k0 + n − 1 into the delay ``line`` and the samples into ``rows``
    (LOG_COLUMNS) from their records (DRIVE_INPUT, ESTIMATE, COMMAND); T_s [s] the sample period."""
    for i in range(n):
        issue_command(line, k0 + i, commands[i].u_alpha_V, commands[i].u_beta_V)
        write_row(rows[i], (k0 + i) * T_s, NO_TRUTH, inputs[i], estimates[i], commands[i])
