"""The one-process closed loop as one compiled kernel, in the contract's lock-step order per sample k:
plant samples currents → estimator answers θ̂, injection → controller answers the voltage → plant
advances to k+1. The cores are the same functions the ROS nodes call."""
from numba import njit

from control_math.current_sensing import corrected_currents
from drive_interface.estimator_states import TRACKING
from foc_controller.control import LAST_U_ALPHA, LAST_U_BETA, controller_step
from pmsm_plant.model import OMEGA_M, THETA_M, plant_advance, plant_outputs, sense_currents


@njit(cache=True)
def write_row(row, t, theta_m, omega_m, tau_e, tau_load, i_a, i_b, i_c, i_a_meas, i_b_meas, i_c_meas,
              theta_e_hat, omega_e_hat, u_alpha, u_beta, u_inj_alpha, u_inj_beta, omega_m_ref, i_d, i_q,
              i_d_ref, i_q_ref, eps, signal, state):
    """Write one sample's values into a log row; the arguments are drive_interface.log.LOG_COLUMNS in
    order (test/test_architecture.py checks it)."""
    row[0] = t
    row[1] = theta_m
    row[2] = omega_m
    row[3] = tau_e
    row[4] = tau_load
    row[5] = i_a
    row[6] = i_b
    row[7] = i_c
    row[8] = i_a_meas
    row[9] = i_b_meas
    row[10] = i_c_meas
    row[11] = theta_e_hat
    row[12] = omega_e_hat
    row[13] = u_alpha
    row[14] = u_beta
    row[15] = u_inj_alpha
    row[16] = u_inj_beta
    row[17] = omega_m_ref
    row[18] = i_d
    row[19] = i_q
    row[20] = i_d_ref
    row[21] = i_q_ref
    row[22] = eps
    row[23] = signal
    row[24] = state


@njit
def run_samples(k_start, k_end, px, machine, mech, inverter, sensor, seed, T_s, substeps,
                est_step, ex, ez, ep, cx, cz, cp, speed_ref, tau_load, tau_ff, imposed, brake, calibration, log):
    """Run samples k_start..k_end−1; row k − k_start of ``log`` receives sample k (LOG_COLUMNS).

    px: plant state (pmsm_plant.model); ex, ez, ep: the estimator's state, filter state and parameters;
    cx, cz, cp: the controller's. speed_ref [rad/s], tau_load and the controller's torque feed-forward
    tau_ff [N·m] are indexed by k; with ``imposed``
    the shaft follows speed_ref. With brake[0] = 1 a holding brake keeps the shaft at rest until sample
    brake[1], set when the estimator first reports tracking to that sample plus brake[2] (the brake's lift
    time in samples). Both cores read the measured currents
    corrected by the commissioned ``calibration`` (control_math.current_sensing); the log keeps them as
    measured. Not cached on disk:
    numba cannot re-save a cache index whose entries are specialised on other processes' step functions
    ("underlying object has vanished"); the kernels it calls are cached.
    """
    n_p = machine.n_p
    for k in range(k_start, k_end):
        i_a, i_b, i_c, tau_e = plant_outputs(px, machine)
        m_a, m_b, m_c = sense_currents(i_a, i_b, i_c, sensor, seed, k)
        c_a, c_b, c_c = corrected_currents(m_a, m_b, m_c, calibration)
        theta_hat, omega_hat, u_inj_a, u_inj_b, eps, signal, state = est_step(
            ex, ez, ep, k, c_a, c_b, c_c, cx[LAST_U_ALPHA], cx[LAST_U_BETA], n_p * px[THETA_M],
            n_p * px[OMEGA_M])
        u_a, u_b, i_d, i_q, i_d_ref, i_q_ref = controller_step(
            cx, cz, cp, c_a, c_b, c_c, theta_hat, omega_hat, speed_ref[k], u_inj_a, u_inj_b, state, tau_ff[k])
        write_row(log[k - k_start], k * T_s, px[THETA_M], px[OMEGA_M], tau_e, tau_load[k], i_a, i_b, i_c,
                  m_a, m_b, m_c, theta_hat, omega_hat, u_a, u_b, u_inj_a, u_inj_b, speed_ref[k], i_d, i_q,
                  i_d_ref, i_q_ref, eps, signal, state)
        if brake[0] > 0.5 and brake[1] < 0.0 and state == TRACKING:
            brake[1] = k + brake[2]
        held = brake[0] > 0.5 and (brake[1] < 0.0 or k < brake[1])
        plant_advance(px, u_a, u_b, tau_load[k], imposed or held, 0.0 if held else speed_ref[k], machine, mech,
                      inverter, T_s, substeps)


@njit
def replay_samples(est_step, ex, ez, ep, n_p, currents, u_prev, theta_m, omega_m, calibration, out):
    """Run an estimator over recorded samples: ``currents`` (n × 3, measured a, b, c; corrected by the
    commissioned ``calibration`` as in the drive), ``u_prev`` (n × 2,
    the voltage command of the sample before), the recorded ground truth θ_m, ω_m (read only by
    `sensored`; NaN becomes 0). ``out`` rows receive θ̂_e, ω̂_e, u_inj_α, u_inj_β, ε, signal, state."""
    for k in range(currents.shape[0]):
        theta = theta_m[k] if theta_m[k] == theta_m[k] else 0.0
        omega = omega_m[k] if omega_m[k] == omega_m[k] else 0.0
        c_a, c_b, c_c = corrected_currents(currents[k, 0], currents[k, 1], currents[k, 2], calibration)
        result = est_step(ex, ez, ep, k, c_a, c_b, c_c, u_prev[k, 0], u_prev[k, 1], n_p * theta, n_p * omega)
        for j in range(7):
            out[k, j] = result[j]
