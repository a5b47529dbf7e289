"""The one-process closed loop as one compiled kernel over blocks of N samples, in the contract's order
per block: the plant samples the block (applying the commands of earlier blocks through the delay line)
→ the estimator answers θ̂, injection → the controller answers the voltages → they enter the delay line.
The block kernels are the same functions the ROS nodes call; with N = 1 this is the lock-step per sample.
"""
from typing import Any, NamedTuple

import numpy as np
from numba import njit

from drive_common.contract.drive_records import COMMAND, DRIVE_INPUT
from drive_common.contract.estimator_records import ESTIMATE
from drive_common.contract.estimator_states import TRACKING
from drive_common.math.command_delay import issue_command
from drive_common.math.current_sensing import CurrentSensing, corrected_currents
from drive_common.math.winding import R_S_IN_USE
from foc_controller.control import controller_block
from foc_controller.protection import protection_block
from hf_estimator.block import EstimatorCore, estimator_block
from pmsm_plant.model import INVERTER_MODE, NOT_RELEASED, bus_voltage, plant_block
from pmsm_plant.params import PlantInputs, PlantParams


class PlantCore(NamedTuple):
    """What the loop steps of the plant (pmsm_plant.build.Plant): its state, delay line, parameters, the
    sensor noise's seed, the period T_s [s] and substeps, and whether the shaft follows the speed table."""

    x: np.ndarray
    line: np.ndarray
    machine: Any
    mechanics: Any
    inverter: Any
    sensor: Any
    seed: int
    T_s: float
    substeps: int
    imposed: bool


class Schedule(NamedTuple):
    """A run's tables indexed by sample k: the speed reference [rad/s], the load [N·m], the robot's torque
    feed-forward to the controller [N·m]; and the brake: [has one (1/0), sample it releases at (−1: not yet
    known), its lift time in samples]."""

    omega_m_ref_rad_s: np.ndarray
    tau_load_Nm: np.ndarray
    tau_feedforward_Nm: np.ndarray
    brake: np.ndarray


class BlockBuffers(NamedTuple):
    """One block's samples as they pass from core to core: the plant's rows (N × 10, pmsm_plant.model.plant_block),
    the drive's inputs (N DRIVE_INPUT records), the estimates (N ESTIMATE) and the commands (N COMMAND)."""

    plant: np.ndarray
    inputs: np.ndarray
    estimates: np.ndarray
    commands: np.ndarray


def block_buffers(block_samples):
    """Zeroed BlockBuffers for blocks of ``block_samples`` samples."""
    return BlockBuffers(np.zeros((block_samples, 10)), np.zeros(block_samples, DRIVE_INPUT),
                        np.zeros(block_samples, ESTIMATE), np.zeros(block_samples, COMMAND))


class DriveCores(NamedTuple):
    """The drive's cores a block steps, with their states: the estimator (EstimatorCore), the controller's
    parameters and states (foc_controller.control), the protections' parameters and state
    (foc_controller.protection) and how the drive reads its currents (CurrentSensing)."""

    estimator: EstimatorCore
    controller: Any
    controller_x: np.ndarray
    controller_z: np.ndarray
    protection: Any
    protection_x: np.ndarray
    sensing: CurrentSensing


@njit(_nrt=False, nogil=True, inline='always')
def drive_block(step, cores, block, line, buffers):
    """The drive's answer to one block in the contract's order, the one sequence every compiled answer runs
    (run_blocks, drive_tools.runner.compiled_answer): ``block`` (k0, n, the bus at its last sample [V]),
    the estimator's ``step`` on ``cores`` (DriveCores) with its resistive drop from the protections' R̂_s,
    the protections over the measured currents, the bus and the last speed estimate, the controller;
    ``buffers``: (the measured currents (n × 3) [A], DRIVE_INPUT, ESTIMATE and COMMAND records), the
    estimates and commands written there; ``line`` the command delay line. The safe state the protections
    tripped into at this block (0: none)."""
    k0, n, u_dc_V = block
    currents, inputs, estimates, commands = buffers
    cores.estimator.sample[0].R_s_ohm = cores.protection_x[R_S_IN_USE]
    estimator_block(step, cores.estimator, k0, n, inputs, line, cores.sensing, estimates)
    safe = protection_block(cores.protection_x, cores.protection, currents, n, k0 + n - 1, u_dc_V,
                            estimates[n - 1].omega_e_hat, cores.controller_x)
    controller_block(cores.controller_x, cores.controller_z, cores.controller, n, inputs, estimates, cores.sensing,
                     commands)
    return safe


def copied(cores):
    """DriveCores with copies of every state (a warm-up's or a probe's: the drive's own states untouched)."""
    e = cores.estimator
    return cores._replace(estimator=EstimatorCore(e.params, e.state.copy(), e.sample.copy()),
                          controller_x=cores.controller_x.copy(), controller_z=cores.controller_z.copy(),
                          protection_x=cores.protection_x.copy())


class ClosedLoop(NamedTuple):
    """Every core of the one-process loop with its state: the plant, the drive's cores (DriveCores), the
    schedule, the block size N and the block's buffers."""

    plant: PlantCore
    drive: DriveCores
    schedule: Schedule
    block_samples: int
    buffers: BlockBuffers


@njit(cache=True, _nrt=False)
def write_row(row, t_s, truth, inputs, estimate, command):
    """Write one sample into a log row in the layout of drive_common.contract.log.LOG_COLUMNS: the time t_s
    [s]; ``truth``, the plant's (θ_m, ω_m, τ_e, τ_load, i_a, i_b, i_c) (zeros where the drive knows none);
    the measured currents and the speed reference of ``inputs`` (DRIVE_INPUT); ``estimate`` (ESTIMATE) and
    ``command`` (COMMAND) (test/test_architecture.py checks every column)."""
    row[0] = t_s
    row[1], row[2], row[3], row[4], row[5], row[6], row[7] = truth
    row[8] = inputs.i_a_A
    row[9] = inputs.i_b_A
    row[10] = inputs.i_c_A
    row[11] = estimate.theta_e_hat
    row[12] = estimate.omega_e_hat
    row[13] = command.u_alpha_V
    row[14] = command.u_beta_V
    row[15] = estimate.u_inj_alpha
    row[16] = estimate.u_inj_beta
    row[17] = inputs.omega_m_ref_rad_s
    row[18] = command.i_d_A
    row[19] = command.i_q_A
    row[20] = command.i_d_ref_A
    row[21] = command.i_q_ref_A
    row[22] = estimate.eps
    row[23] = estimate.signal
    row[24] = estimate.state
    row[25] = estimate.injection_amplitude
    row[26] = estimate.observer_weight
    row[27] = estimate.leader


@njit(_nrt=False, inline='always')
def run_blocks(step, loop, k_start, k_end, log):
    """Run samples k_start..k_end−1 (k_start a multiple of the block size N) of ``loop`` (ClosedLoop), its
    estimator's step kernel ``step``, in blocks of N samples; row k − k_start of ``log`` receives sample k
    (LOG_COLUMNS).

    With ``imposed`` the shaft follows the speed reference. With brake[0] = 1 a holding brake keeps the
    shaft at rest until sample brake[1], set when the estimator first reports tracking at sample k_t: k_t
    plus brake[2] (the brake's lift time in samples), but no earlier than the first period simulated after
    the block that reported it (the plant of a graph learns it with that block). Estimator and controller
    read the measured currents corrected by the commissioned calibration and treat currents beyond the trip
    as bad input (hf_estimator.block, foc_controller.control.controller_block); the log keeps them as
    measured. Before the controller answers a block the drive's protections take its measured currents, the
    bus at its last sample and the speed estimate there; a trip switches the inverter to the safe state
    they chose from the next period on; the estimator's resistive drop takes their R̂_s (R_S_IN_USE) from
    the next block on.
    Called bound to the step (drive_common.runtime.bound_kernels: cached on disk per step), inlined into the
    bound caller so that the step is only ever called, never passed on as a value (which numba cannot cache). Like
    every kernel on the per-sample path it allocates nothing and is compiled without reference counting
    (``_nrt=False``: the counts' atomic updates at each call cost a tenth of a sample's time with N = 1); the
    block kernels are inlined into it (``inline='always'``: a call copies its parameters, flattened, onto the
    stack, a tenth again).
    """
    px, line, machine, mech, inverter, sensor, seed, T_s, substeps, imposed = loop.plant
    speed_ref, tau_load, tau_ff, brake = loop.schedule
    cores = loop.drive
    n_p = machine.n_p
    plant_out, inputs, est_out, ctrl_out = loop.buffers
    for k0 in range(k_start, k_end, loop.block_samples):
        n = min(loop.block_samples, k_end - k0)
        release = -1
        if brake[0] > 0.5:
            release = NOT_RELEASED if brake[1] < 0.0 else int(brake[1])
        plant_block(px, line, k0, n, PlantInputs(tau_load, speed_ref, imposed, release),
                    PlantParams(machine, mech, inverter, sensor, seed, T_s, substeps), plant_out)
        for i in range(n):
            p, s = plant_out[i], inputs[i]
            s.i_a_A, s.i_b_A, s.i_c_A = p[3], p[4], p[5]
            s.theta_e_encoder_rad, s.omega_e_encoder_rad_s = n_p * p[6], n_p * p[7]
            s.omega_m_ref_rad_s, s.tau_feedforward_Nm = speed_ref[k0 + i], tau_ff[k0 + i]
        safe = drive_block(step, cores, (k0, n, bus_voltage(px, inverter)), line,
                           (plant_out[:, 3:6], inputs, est_out, ctrl_out))
        if safe:
            px[INVERTER_MODE] = safe
        for i in range(n):
            k = k0 + i
            p, e, c = plant_out[i], est_out[i], ctrl_out[i]
            issue_command(line, k, c.u_alpha_V, c.u_beta_V)
            if brake[0] > 0.5 and brake[1] < 0.0 and e.state == TRACKING:
                brake[1] = max(k + brake[2], k0 + n - 1)
            write_row(log[k - k_start], k * T_s, (p[6], p[7], p[8], p[9], p[0], p[1], p[2]), inputs[i], e, c)


@njit(inline='always')
def replay_samples(step, core, currents, u_applied, encoder, whole, calibration, out):
    """Run an estimator's ``step`` on ``core`` (hf_estimator.block.EstimatorCore) over recorded samples:
    ``currents`` (n × 3, measured a, b, c; corrected by the commissioned ``calibration`` as in the drive),
    ``u_applied`` (n × 2, the voltage command that acted in the period before each sample: the command of
    d + 1 samples before, d the recorded drive's delay), and ``encoder`` (n × 2), the electrical angle [rad]
    and speed [rad/s] handed to the kernel's encoder inputs (``sensored`` reads the recorded ground truth
    there; an injecting estimator replayed with ``polarity_from_recording`` reads the recorded drive's
    estimate, hf_estimator.startup item 5). ``out``: one ESTIMATE record per sample. Where ``whole`` is false
    (a sample the recording lost) the estimator is not stepped: it meets the next sample, its index k kept, as
    a drive node meets a lost message; its record is NaN."""
    ep, ex = core.params, core.state[0]
    sample = core.sample[0]
    for k in range(currents.shape[0]):
        if not whole[k]:
            out[k].theta_e_hat = out[k].omega_e_hat = out[k].u_inj_alpha = out[k].u_inj_beta = np.nan
            out[k].eps = out[k].signal = out[k].state = np.nan
            out[k].injection_amplitude = out[k].observer_weight = out[k].leader = np.nan
            continue
        sample.i_a, sample.i_b, sample.i_c = corrected_currents(currents[k, 0], currents[k, 1], currents[k, 2],
                                                                calibration)
        sample.u_applied_alpha, sample.u_applied_beta = u_applied[k, 0], u_applied[k, 1]
        sample.theta_e_encoder, sample.omega_e_encoder = encoder[k, 0], encoder[k, 1]
        step(ex, ep, k, sample, out[k])
