"""What the drive's controller side reads and writes per sample, as named records (numpy structured dtypes
that numba kernels read and write by field name), beside the estimator's (estimator_records): one
definition each, for the runner's loop, the bridge's host, the nodes and the tests."""
import numpy as np

from . import numba_records  # noqa: F401  (record kernels cached safely: numba_records.py)

DRIVE_INPUT = np.dtype([("i_a_A", np.float64), ("i_b_A", np.float64), ("i_c_A", np.float64),
                        ("theta_e_encoder_rad", np.float64), ("omega_e_encoder_rad_s", np.float64),
                        ("omega_m_ref_rad_s", np.float64), ("tau_feedforward_Nm", np.float64)])
"""What the drive takes in at sample k: the phase currents as measured [A] (uncorrected: the block kernels
check them against the trip and correct them), the encoder's electrical angle [rad] and speed [rad/s] (read
only by ``sensored``; 0 without one), the mechanical speed reference [rad/s] and the robot's torque
feed-forward [N·m]."""

COMMAND = np.dtype([("u_alpha_V", np.float64), ("u_beta_V", np.float64), ("i_d_A", np.float64),
                    ("i_q_A", np.float64), ("i_d_ref_A", np.float64), ("i_q_ref_A", np.float64)])
"""The controller's answer to sample k: the stator voltage command (αβ) [V] for the period after it, the
HF-rejected feedback currents i_d, i_q and their references i_d*, i_q* [A]."""


def drive_inputs(n):
    """A block of n DRIVE_INPUT records, zeroed."""
    return np.zeros(n, DRIVE_INPUT)


def commands(n):
    """A block of n COMMAND records, zeroed."""
    return np.zeros(n, COMMAND)
