"""A run's log: one row per sample, one column per quantity (SI units, angles as named). The runner's
kernel, the graph's recorder and the bag reader all fill this layout; messages go into rows through
``fill_sample`` and the topic table."""
import math

import numpy as np

from .topics import TOPICS

LOG_COLUMNS = ("t", "theta_m", "omega_m", "tau_e", "tau_load", "i_a", "i_b", "i_c",
               "i_a_meas", "i_b_meas", "i_c_meas", "theta_e_hat", "omega_e_hat", "u_alpha", "u_beta",
               "u_inj_alpha", "u_inj_beta", "omega_m_ref", "i_d", "i_q", "i_d_ref", "i_q_ref",
               "eps", "signal", "state", "injection_amplitude", "observer_weight", "leader")
"""t [s]; θ_m, ω_m: true mechanical angle [rad] and speed [rad/s]; τ_e, τ_load [N·m]; true and measured
phase currents [A]; θ̂_e, ω̂_e: electrical estimates; the voltage command and the injection in it [V,
αβ]; ω*_m [rad/s]; the controller's i_d, i_q and references [A]; the estimator's ε, signal and
start-up state code (0 hold, 1 aligning, 2 polarity test, 3 tracking, 4 lock lost); the injection's carrier
amplitude [V], the back-EMF observer's weight in θ̂ (0 … 1) and the source θ̂ follows (0 injection, 1
back-EMF, 2 encoder)."""
COLUMN = {name: i for i, name in enumerate(LOG_COLUMNS)}


def fill_sample(row, topic, msg, n_p):
    """Write what a per-sample message of ``topic`` says into its log row: rclpy and rosbags messages
    alike, so a recording from the graph and one read back from a bag fill the same columns."""
    if TOPICS[topic].type.endswith("Vector3Stamped"):
        v = msg.vector
        fill_values(row, topic, (v.x, v.y, v.z), n_p)
    elif len(msg.position):
        fill_values(row, topic, (msg.position[0], msg.velocity[0] if len(msg.velocity) else math.nan,
                                 msg.effort[0] if len(msg.effort) else math.nan), n_p)


def fill_values(row, topic, values, n_p):
    """Write a per-sample message's values into its log row: x, y, z of a Vector3Stamped; the first
    position, velocity and effort of a JointState (None: not carried), mechanical values of an
    ``electrical`` topic scaled to electrical ones."""
    t = TOPICS[topic]
    scale = n_p if t.electrical else 1.0
    for column, value in zip(t.log_columns, values):
        row[COLUMN[column]] = math.nan if value is None else scale * value


def fill_block(log, k0, topic, channels, n_p):
    """Write a block message of ``topic`` (a block twin, drive_common.contract.topics.BLOCK_TOPIC) into the rows
    k0 … of ``log``: its channels (position, velocity, effort arrays of n samples; empty: not carried)
    fill the per-sample topic's columns, as its n per-sample messages would. Rows beyond the log are left
    out."""
    t = TOPICS[topic]
    scale = n_p if t.electrical else 1.0
    for column, values in zip(t.log_columns, channels):
        count = min(len(values), log.shape[0] - k0)
        if count > 0:
            log[k0:k0 + count, COLUMN[column]] = scale * np.asarray(values[:count])
