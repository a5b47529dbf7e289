"""The one-process closed loop as one compiled kernel over blocks of N samples, in the contract's order
per block: the plant samples the block (applying the commands of earlier blocks through the delay line)
→ the estimator answers θ̂, injection → the controller answers the voltages → they enter the delay line.
The block kernels are the same functions the ROS nodes call; with N = 1 this is the lock-step per sample.
"""
import numpy as np
from numba import njit

from drive_common.contract.estimator_records import ESTIMATE, SAMPLE
from drive_common.contract.estimator_states import TRACKING
from drive_common.math.command_delay import issue_command
from drive_common.math.current_sensing import corrected_currents
from drive_common.math.winding import R_S_IN_USE
from foc_controller.control import controller_block
from foc_controller.protection import protection_block
from hf_estimator.block import estimator_block
from pmsm_plant.model import INVERTER_MODE, NOT_RELEASED, bus_voltage, plant_block
from pmsm_plant.params import PlantInputs, PlantParams


@njit(cache=True)
def write_row(row, t, theta_m, omega_m, tau_e, tau_load, i_a, i_b, i_c, i_a_meas, i_b_meas, i_c_meas,
              theta_e_hat, omega_e_hat, u_alpha, u_beta, u_inj_alpha, u_inj_beta, omega_m_ref, i_d, i_q,
              i_d_ref, i_q_ref, eps, signal, state, injection_amplitude, observer_weight, leader):
    """Write one sample's values into a log row; the arguments are drive_common.contract.log.LOG_COLUMNS in
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
    row[25] = injection_amplitude
    row[26] = observer_weight
    row[27] = leader


@njit
def run_blocks(k_start, k_end, block, px, line, machine, mech, inverter, sensor, seed, T_s, substeps,
               est_step, est_state, ep, cx, cz, cp, speed_ref, tau_load, tau_ff, imposed, brake, calibration, trip_A,
               ps, pp, log):
    """Run samples k_start..k_end−1 (k_start a multiple of ``block``) in blocks of ``block`` samples;
    row k − k_start of ``log`` receives sample k (LOG_COLUMNS).

    px: plant state (pmsm_plant.model); line: the delay line (drive_common.math.command_delay); est_state, ep:
    the estimator's state (Estimator.state) and parameters; cx, cz, cp: the controller's state, filter state and
    parameters. speed_ref [rad/s], tau_load and the controller's torque feed-forward tau_ff [N·m] are
    indexed by k; with ``imposed``
    the shaft follows speed_ref. With brake[0] = 1 a holding brake keeps the shaft at rest until sample
    brake[1], set when the estimator first reports tracking at sample k_t: k_t plus brake[2] (the brake's
    lift time in samples), but no earlier than the first period simulated after the block that reported
    it (the plant of a graph learns it with that block). Estimator and controller read the measured
    currents corrected by the commissioned ``calibration`` and treat currents beyond ``trip_A`` [A] as bad
    input (hf_estimator.block, foc_controller.control.controller_block); the log keeps them as measured.
    Before the controller answers a block the drive's protections (ps, pp: foc_controller.protection's state
    and parameters) take its measured currents, the bus at its last sample and the speed estimate there;
    a trip switches the inverter to the safe state they chose from the next period on; the estimator's
    resistive drop takes their R̂_s (R_S_IN_USE) from the next block on.
    Not cached on disk: numba cannot re-save a cache index whose entries are specialised on other
    processes' step functions ("underlying object has vanished"); the kernels it calls are cached.
    """
    n_p = machine.n_p
    plant_out = np.zeros((block, 10))
    est_out = np.zeros(block, ESTIMATE)
    inputs = np.zeros(1, SAMPLE)
    ctrl_out = np.zeros((block, 6))
    encoder = np.zeros((block, 2))
    for k0 in range(k_start, k_end, block):
        n = min(block, k_end - k0)
        release = -1
        if brake[0] > 0.5:
            release = NOT_RELEASED if brake[1] < 0.0 else int(brake[1])
        plant_block(px, line, k0, n, PlantInputs(tau_load, speed_ref, imposed, release),
                    PlantParams(machine, mech, inverter, sensor, seed, T_s, substeps), plant_out)
        for i in range(n):
            encoder[i, 0] = n_p * plant_out[i, 6]
            encoder[i, 1] = n_p * plant_out[i, 7]
        inputs[0].R_s_ohm = ps[R_S_IN_USE]
        estimator_block(est_step, est_state, ep, k0, n, plant_out[:, 3:6], line, encoder, calibration, trip_A,
                        est_out, inputs)
        safe = protection_block(ps, pp, plant_out[:, 3:6], n, k0 + n - 1, bus_voltage(px, inverter),
                                est_out[n - 1].omega_e_hat, cx)
        if safe:
            px[INVERTER_MODE] = safe
        controller_block(cx, cz, cp, n, plant_out[:, 3:6], est_out, speed_ref[k0:k0 + n], tau_ff[k0:k0 + n],
                         calibration, trip_A, ctrl_out)
        for i in range(n):
            k = k0 + i
            p, e, c = plant_out[i], est_out[i], ctrl_out[i]
            issue_command(line, k, c[0], c[1])
            if brake[0] > 0.5 and brake[1] < 0.0 and e.state == TRACKING:
                brake[1] = max(k + brake[2], k0 + n - 1)
            write_row(log[k - k_start], k * T_s, p[6], p[7], p[8], p[9], p[0], p[1], p[2], p[3], p[4], p[5],
                      e.theta_e_hat, e.omega_e_hat, c[0], c[1], e.u_inj_alpha, e.u_inj_beta, speed_ref[k], c[2], c[3],
                      c[4], c[5], e.eps, e.signal, e.state, e.injection_amplitude, e.observer_weight, e.leader)


@njit
def replay_samples(est_step, est_state, ep, currents, u_applied, whole, theta_e_reference, omega_e_reference,
                   calibration, out):
    """Run an estimator over recorded samples: ``currents`` (n × 3, measured a, b, c; corrected by the
    commissioned ``calibration`` as in the drive), ``u_applied`` (n × 2, the voltage command that acted
    in the period before each sample: the command of d + 1 samples before, d the recorded drive's delay),
    and the electrical angle and speed handed to the kernel's encoder inputs (``sensored`` reads the
    recorded ground truth there; an injecting estimator replayed with ``polarity_from_recording`` reads the
    recorded drive's estimate, hf_estimator.startup item 5). ``out``: one ESTIMATE record per sample.
    Where ``whole`` is false (a sample the recording lost) the estimator is not stepped: it meets the next
    sample, its index k kept, as a drive node meets a lost message; its record is NaN."""
    ex = est_state[0]
    sample = np.zeros(1, SAMPLE)[0]
    for k in range(currents.shape[0]):
        if not whole[k]:
            out[k].theta_e_hat = out[k].omega_e_hat = out[k].u_inj_alpha = out[k].u_inj_beta = np.nan
            out[k].eps = out[k].signal = out[k].state = np.nan
            out[k].injection_amplitude = out[k].observer_weight = out[k].leader = np.nan
            continue
        sample.i_a, sample.i_b, sample.i_c = corrected_currents(currents[k, 0], currents[k, 1], currents[k, 2],
                                                                calibration)
        sample.u_applied_alpha, sample.u_applied_beta = u_applied[k, 0], u_applied[k, 1]
        sample.theta_e_encoder, sample.omega_e_encoder = theta_e_reference[k], omega_e_reference[k]
        est_step(ex, ep, k, sample, out[k])
