"""Continuous-time PMSM, averaged inverter and sampled current sensing as numba kernels.

The stator flux linkage in the stationary frame is the electrical state, so the piecewise-constant
inverter voltage is integrated without approximation and only the slow resistive and mechanical terms
go through the Runge-Kutta step; HF injection at any frequency below Nyquist is integrated accurately
(see test/test_plant.py). One control period is: apply the voltage the delay line holds for it
(drive_common.math.command_delay) → integrate → sample.

Beside the machine the state holds the DC link (a capacitor above a supply that only sources, with an
optional brake chopper), the winding's temperature rise (R_s follows it) and the inverter's switching
mode: PWM, or one of its two safe states, freewheel (all switches off: the diodes rectify whatever
back-EMF exceeds the bus) and active short circuit (all low-side switches on: u = 0). docs/protections.md.
"""
import math

import numpy as np
from numba import njit

from drive_common.math.command_delay import applied_voltage
from drive_common.math.copper import copper_resistance
from drive_common.math.frames import clarke, inverse_clarke, rotate
from drive_common.math.safe_state import ASC, FREEWHEEL

# Plant state vector layout: flux [Wb], shaft [rad/s, rad], DC-link voltage above the supply's [V] (0
# reads as the supply's: bus_voltage), winding temperature rise [K], inverter mode (drive_common.math.safe_state:
# PWM, FREEWHEEL, ASC), brake chopper on (1).
PSI_ALPHA, PSI_BETA, OMEGA_M, THETA_M, U_DC_BUS, WINDING_RISE, INVERTER_MODE, BRAKE_ON = range(8)
N_STATE = 8
NOT_RELEASED = 2 ** 62
"""plant_block's ``release_k`` of a brake that holds until further notice."""


@njit(cache=True)
def magnet_equivalent_current(m):
    """i_f of MachineParams: the d-current the magnetic energy gradient gives at ψ = (ψ_f, 0)."""
    return m.psi_f_Wb / m.L_d_H + m.a_d * m.psi_f_Wb ** 5


@njit(cache=True)
def current_from_flux(psi_d, psi_q, m):
    """Rotor-frame currents from flux linkages (MachineParams docstring model)."""
    abs_d = abs(psi_d)
    i_d = (psi_d / m.L_d_H + m.a_d * psi_d ** 5 + 0.5 * m.a_dq * abs_d * psi_d * psi_q * psi_q
           - magnet_equivalent_current(m))
    i_q = psi_q / m.L_q_H + m.a_q * psi_q ** 3 + (m.a_dq / 3.0) * abs_d ** 3 * psi_q
    return i_d, i_q


@njit(cache=True)
def incremental_inverse_inductance(psi_d, psi_q, m):
    """Γ = ∂i/∂ψ (the Hessian of the magnetic energy): (Γ_dd, Γ_qq, Γ_dq) [1/H]."""
    abs_d = abs(psi_d)
    g_dd = 1.0 / m.L_d_H + 5.0 * m.a_d * psi_d ** 4 + m.a_dq * abs_d * psi_q * psi_q
    g_qq = 1.0 / m.L_q_H + 3.0 * m.a_q * psi_q * psi_q + (m.a_dq / 3.0) * abs_d ** 3
    g_dq = m.a_dq * abs_d * psi_d * psi_q
    return g_dd, g_qq, g_dq


@njit(cache=True)
def stator_current(psi_alpha, psi_beta, theta_m, m):
    """Stationary-frame currents (i_α, i_β) from the stationary flux and the mechanical angle."""
    theta_e = m.n_p * theta_m
    psi_d, psi_q = rotate(psi_alpha, psi_beta, -theta_e)
    i_d, i_q = current_from_flux(psi_d, psi_q, m)
    return rotate(i_d, i_q, theta_e)


@njit(cache=True)
def electromagnetic_torque(psi_alpha, psi_beta, i_alpha, i_beta, n_p):
    """τ_e = 1.5 p (ψ_α i_β − ψ_β i_α); equals Szabó Eq. (3) for the linear model."""
    return 1.5 * n_p * (psi_alpha * i_beta - psi_beta * i_alpha)


@njit(cache=True)
def duty_cycles(u_alpha, u_beta, U_dc):
    """Space-vector (min-max zero-sequence) PWM duties in [0, 1]; beyond the hexagon they clip."""
    u_a, u_b, u_c = inverse_clarke(u_alpha, u_beta)
    u_0 = -0.5 * (max(u_a, u_b, u_c) + min(u_a, u_b, u_c))
    d_a = min(max(0.5 + (u_a + u_0) / U_dc, 0.0), 1.0)
    d_b = min(max(0.5 + (u_b + u_0) / U_dc, 0.0), 1.0)
    d_c = min(max(0.5 + (u_c + u_0) / U_dc, 0.0), 1.0)
    return d_a, d_b, d_c


@njit(cache=True)
def inverter_voltage(d_a, d_b, d_c, i_alpha, i_beta, inv, T_s, U_dc):
    """Average stator voltage (u_α, u_β) realised by the duties on the bus U_dc [V], with the dead-time
    voltage error of InverterParams inv."""
    u_a = d_a * U_dc
    u_b = d_b * U_dc
    u_c = d_c * U_dc
    if inv.t_dead_s > 0.0:
        i_a, i_b, i_c = inverse_clarke(i_alpha, i_beta)
        u_err = inv.t_dead_s / T_s * U_dc
        u_a -= u_err * math.tanh(i_a / inv.i_dead_A)
        u_b -= u_err * math.tanh(i_b / inv.i_dead_A)
        u_c -= u_err * math.tanh(i_c / inv.i_dead_A)
    return clarke(u_a, u_b, u_c)


@njit(cache=True)
def bus_voltage(x, inv):
    """The DC-link voltage [V] of state x: the capacitor's, never below the supply's U_dc_V."""
    return max(x[U_DC_BUS], inv.U_dc_V)


@njit(cache=True)
def winding_resistance(x, m):
    """R_s(T) = R_s,20 (1 + α (T − 20 °C)) [Ω] at the winding temperature T = T_ambient + x[WINDING_RISE]
    (drive_common.math.copper); R_s_ohm itself when the winding is isothermal (C_th_J_K = 0)."""
    if m.C_th_J_K <= 0.0:
        return m.R_s_ohm
    return copper_resistance(m.R_s_ohm, 20.0, m.T_ambient_degC + x[WINDING_RISE])


@njit(cache=True)
def _spring_damper(depth_rad, omega_m, mech):
    """k d + b ω_m [N·m] of the end stops of ``mech`` at a depth ``d`` [rad] into one, at ``omega_m`` [rad/s]."""
    return mech.stop_stiffness_Nm_rad * depth_rad + mech.stop_damping_Nms_rad * omega_m


@njit(cache=True)
def end_stop_torque(theta_m, omega_m, mech):
    """The torque [N·m] an end stop of ``mech`` (MechanicsParams) opposes the shaft with at angle ``theta_m`` [rad]
    and speed ``omega_m`` [rad/s]: k (θ_m − θ_stop) + b ω_m beyond a stop, the damper only pushing back (a stop
    does not pull the shaft back onto itself); 0 between the stops."""
    if theta_m > mech.stop_high_rad:
        return max(0.0, _spring_damper(theta_m - mech.stop_high_rad, omega_m, mech))
    if theta_m < mech.stop_low_rad:
        return min(0.0, _spring_damper(theta_m - mech.stop_low_rad, omega_m, mech))
    return 0.0


@njit(cache=True)
def _derivatives(s, drive, m, mech, R_s):
    """Time derivatives of the state s = (ψ_α, ψ_β [Wb], ω_m [rad/s], θ_m [rad]) under drive = (u_α, u_β
    [V], τ_load [N·m], imposed, ω_imposed [rad/s]): dψ/dt = u − R_s i (R_s [Ω]), the shaft's torque
    balance (or the imposed speed)."""
    return _derivatives_at(s, stator_current(s[0], s[1], s[3], m), drive, m, mech, R_s)


@njit(cache=True)
def _derivatives_at(s, i, drive, m, mech, R_s):
    """_derivatives where the state's currents i = (i_α, i_β) [A] are known already."""
    psi_a, psi_b, omega_m, theta_m = s
    u_a, u_b, tau_load, imposed, omega_imposed = drive
    i_a, i_b = i
    tau_e = electromagnetic_torque(psi_a, psi_b, i_a, i_b, m.n_p)
    if imposed:
        d_omega = 0.0
        d_theta = omega_imposed
    else:
        if theta_m > mech.stop_high_rad or theta_m < mech.stop_low_rad:
            tau_load = tau_load + end_stop_torque(theta_m, omega_m, mech)
        d_omega = (tau_e - tau_load - mech.B_Nms * omega_m) / mech.J_kgm2
        d_theta = omega_m
    return u_a - R_s * i_a, u_b - R_s * i_b, d_omega, d_theta


@njit(cache=True, _nrt=False, inline='always')
def _bridge_voltage(x, u, i0, p, U_dc, R_s):
    """Duties (d_a, d_b, d_c) and the average stator voltage (u_α, u_β) [V] the bridge applies in the
    period, by its mode x[INVERTER_MODE]: PWM realises the command u = (u_α, u_β) [V] on the bus U_dc with
    its dead time; ASC applies 0; in freewheel the diodes oppose the current i0 = (i_α, i_β) [A] at the
    period start as hard as the bus lets them: the voltage that would bring the current to zero within
    the period, u₀ = (ψ₀(t+T_s) − ψ)/T_s + R_s i/2 (ψ₀ the magnet's flux, i = 0), clipped to the bridge's
    hexagon. Below the bus the current stays near zero; a back-EMF above it is rectified into the bus.
    p: PlantParams."""
    m, T_s = p.machine, p.T_s_s
    i_alpha, i_beta = i0
    mode = int(x[INVERTER_MODE])
    if mode == ASC:
        return 0.0, 0.0, 0.0, 0.0, 0.0
    if mode == FREEWHEEL:
        theta_next = m.n_p * (x[THETA_M] + x[OMEGA_M] * T_s)
        psi_a0, psi_b0 = rotate(m.psi_f_Wb, 0.0, theta_next)
        u_0a = (psi_a0 - x[PSI_ALPHA]) / T_s + 0.5 * R_s * i_alpha
        u_0b = (psi_b0 - x[PSI_BETA]) / T_s + 0.5 * R_s * i_beta
        d_a, d_b, d_c = duty_cycles(u_0a, u_0b, U_dc)
        v_a, v_b = clarke(d_a * U_dc, d_b * U_dc, d_c * U_dc)
        return d_a, d_b, d_c, v_a, v_b
    d_a, d_b, d_c = duty_cycles(u[0], u[1], U_dc)
    v_a, v_b = inverter_voltage(d_a, d_b, d_c, i_alpha, i_beta, p.inverter, T_s, U_dc)
    return d_a, d_b, d_c, v_a, v_b


@njit(cache=True, _nrt=False)
def _link_and_winding(x, duties, i0, i1, p, U_dc, R_s):
    """The period's DC link and winding heat from the duties (d_a, d_b, d_c) and the currents (i_α, i_β)
    [A] at its start (i0) and end (i1): i_dc = Σ d_x i_x (period average), C dU/dt = −i_dc − i_brake above
    the supply, the chopper's hysteresis at the period start; C_th dΔT/dt = 1.5 R_s |i|² − ΔT/R_th
    (explicit, τ_th ≫ T_s). Nothing to do for a stiff link (C_dc_F = ∞) and an isothermal winding."""
    inv, m, T_s = p.inverter, p.machine, p.T_s_s
    i0_alpha, i0_beta = i0
    i1_alpha, i1_beta = i1
    if math.isfinite(inv.C_dc_F):
        d_a, d_b, d_c = duties
        p_a, p_b, p_c = inverse_clarke(0.5 * (i0_alpha + i1_alpha), 0.5 * (i0_beta + i1_beta))
        i_dc = d_a * p_a + d_b * p_b + d_c * p_c
        if math.isfinite(inv.R_brake_ohm):
            if U_dc > inv.U_brake_on_V:
                x[BRAKE_ON] = 1.0
            elif U_dc < inv.U_brake_off_V:
                x[BRAKE_ON] = 0.0
        i_brake = U_dc / inv.R_brake_ohm if x[BRAKE_ON] > 0.5 else 0.0
        x[U_DC_BUS] = max(U_dc - T_s * (i_dc + i_brake) / inv.C_dc_F, inv.U_dc_V)
    if m.C_th_J_K > 0.0:
        i_sq = 0.5 * (i0_alpha ** 2 + i0_beta ** 2 + i1_alpha ** 2 + i1_beta ** 2)
        x[WINDING_RISE] += T_s / m.C_th_J_K * (1.5 * R_s * i_sq - x[WINDING_RISE] / m.R_th_K_W)


@njit(cache=True, _nrt=False)
def _period(x, u, i0, tau_load_Nm, imposed, omega_imposed, p):
    """plant_advance with the currents i0 = (i_α, i_β) [A] of the state at the period start given (the
    first Runge-Kutta stage's); returns those at its end (the next sample's), which the DC link and the
    winding need too. Four current evaluations a substep."""
    m = p.machine
    U_dc = bus_voltage(x, p.inverter)
    R_s = winding_resistance(x, m)
    if imposed:
        x[OMEGA_M] = omega_imposed
    d_a, d_b, d_c, v_a, v_b = _bridge_voltage(x, u, i0, p, U_dc, R_s)
    drive = (v_a, v_b, tau_load_Nm, imposed, omega_imposed)
    h = p.T_s_s / p.substeps
    i_step = i0
    for _ in range(p.substeps):
        s0, s1, s2, s3 = x[PSI_ALPHA], x[PSI_BETA], x[OMEGA_M], x[THETA_M]
        k1 = _derivatives_at((s0, s1, s2, s3), i_step, drive, m, p.mechanics, R_s)
        k2 = _derivatives((s0 + 0.5 * h * k1[0], s1 + 0.5 * h * k1[1], s2 + 0.5 * h * k1[2],
                           s3 + 0.5 * h * k1[3]), drive, m, p.mechanics, R_s)
        k3 = _derivatives((s0 + 0.5 * h * k2[0], s1 + 0.5 * h * k2[1], s2 + 0.5 * h * k2[2],
                           s3 + 0.5 * h * k2[3]), drive, m, p.mechanics, R_s)
        k4 = _derivatives((s0 + h * k3[0], s1 + h * k3[1], s2 + h * k3[2], s3 + h * k3[3]),
                          drive, m, p.mechanics, R_s)
        x[PSI_ALPHA] = s0 + h / 6.0 * (k1[0] + 2.0 * k2[0] + 2.0 * k3[0] + k4[0])
        x[PSI_BETA] = s1 + h / 6.0 * (k1[1] + 2.0 * k2[1] + 2.0 * k3[1] + k4[1])
        x[OMEGA_M] = s2 + h / 6.0 * (k1[2] + 2.0 * k2[2] + 2.0 * k3[2] + k4[2])
        x[THETA_M] = s3 + h / 6.0 * (k1[3] + 2.0 * k2[3] + 2.0 * k3[3] + k4[3])
        i_step = stator_current(x[PSI_ALPHA], x[PSI_BETA], x[THETA_M], m)
    _link_and_winding(x, (d_a, d_b, d_c), i0, i_step, p, U_dc, R_s)
    return i_step


@njit(cache=True)
def plant_advance(x, u_alpha_V, u_beta_V, tau_load_Nm, imposed, omega_imposed_rad_s, p):
    """Advance the plant state x by one control period p.T_s_s [s] under the voltage command acting in it
    (u_α, u_β) [V] (the delay line's, drive_common.math.command_delay) and the load torque [N·m]. State x
    (N_STATE): PSI_ALPHA … BRAKE_ON; p: PlantParams.

    The inverter realises the command on its bus as one average voltage over the period, its dead-time
    error set by the current polarities at the period start (the switching edges), unless its mode
    (x[INVERTER_MODE]) is a safe state (_bridge_voltage). R_s is the winding's at the period start. With
    ``imposed`` the shaft runs at ``omega_imposed_rad_s`` (dynamometer mode).
    """
    i0 = stator_current(x[PSI_ALPHA], x[PSI_BETA], x[THETA_M], p.machine)
    _period(x, (u_alpha_V, u_beta_V), i0, tau_load_Nm, imposed, omega_imposed_rad_s, p)


@njit(cache=True)
def _phase_outputs(x, i_alpha, i_beta, n_p):
    """True phase currents (i_a, i_b, i_c) [A] and torque τ_e [N·m] of the state x whose stationary-frame
    currents are (i_α, i_β) [A]."""
    tau_e = electromagnetic_torque(x[PSI_ALPHA], x[PSI_BETA], i_alpha, i_beta, n_p)
    p_a, p_b, p_c = inverse_clarke(i_alpha, i_beta)
    return p_a, p_b, p_c, tau_e


@njit(cache=True)
def plant_outputs(x, m):
    """True phase currents (i_a, i_b, i_c) [A] and torque τ_e [N·m] at the state x (MachineParams m)."""
    i_a, i_b = stator_current(x[PSI_ALPHA], x[PSI_BETA], x[THETA_M], m)
    return _phase_outputs(x, i_a, i_b, m.n_p)


@njit(cache=True, _nrt=False, inline='always')
def plant_block(x, line, k0, n, inputs, p, out):
    """Samples k0 … k0+n−1 of the plant: for each k, the period k−1 under the voltage the delay line
    ``line`` holds for it (none before sample 0), then the sample. ``inputs``: PlantInputs (load and
    speed per period, indexed by k; the brake's release); p: PlantParams. Rows of ``out`` (n × 10): true
    i_a, i_b, i_c [A], measured m_a, m_b, m_c [A] (sense_currents), θ_m [rad], ω_m [rad/s], τ_e [N·m],
    the load of the period that follows [N·m]. A block reads only commands of earlier blocks when the
    line's delay is at least n − 1. A period's end currents are the sample's: computed once."""
    m = p.machine
    i_now = stator_current(x[PSI_ALPHA], x[PSI_BETA], x[THETA_M], m)
    for i in range(n):
        k = k0 + i
        if k > 0:
            j = k - 1
            held = j < inputs.release_k
            i_now = _period(x, applied_voltage(line, j), i_now, inputs.load_Nm[j], inputs.imposed or held,
                            0.0 if held else inputs.speed_rad_s[j], p)
        i_a, i_b, i_c, tau_e = _phase_outputs(x, i_now[0], i_now[1], m.n_p)
        m_a, m_b, m_c = sense_currents(i_a, i_b, i_c, p.sensor, p.seed, k)
        row = out[i]
        row[0], row[1], row[2] = i_a, i_b, i_c
        row[3], row[4], row[5] = m_a, m_b, m_c
        row[6], row[7], row[8], row[9] = x[THETA_M], x[OMEGA_M], tau_e, inputs.load_Nm[k]


@njit(cache=True)
def plant_reset(x, theta_m, omega_m, m):
    """Reset the state x to rest electrically (i = 0) at the shaft angle θ_m [rad] and speed ω_m [rad/s]."""
    x[:] = 0.0
    psi_a, psi_b = rotate(m.psi_f_Wb, 0.0, m.n_p * theta_m)
    x[PSI_ALPHA] = psi_a
    x[PSI_BETA] = psi_b
    x[OMEGA_M] = omega_m
    x[THETA_M] = theta_m


@njit(cache=True)
def _splitmix64(z):
    """SplitMix64: a uint64 → a well-mixed uint64 (the counter-based generator's hash)."""
    z = z + np.uint64(0x9E3779B97F4A7C15)
    z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    return z ^ (z >> np.uint64(31))


@njit(cache=True)
def gaussian(seed, k, channel):
    """Standard normal number for (seed, sample k, channel): counter-based, so any composition of the
    cores (one process or a ROS graph) draws the same noise for the same sample."""
    h1 = _splitmix64(np.uint64(seed) * np.uint64(0x100000001B3) ^ np.uint64(4 * k + channel))
    h2 = _splitmix64(h1)
    u1 = (float(h1 >> np.uint64(11)) + 1.0) * (1.0 / 9007199254740992.0)
    u2 = float(h2 >> np.uint64(11)) * (1.0 / 9007199254740992.0)
    return math.sqrt(-2.0 * math.log(u1)) * math.cos(2.0 * math.pi * u2)


@njit(cache=True)
def _adc(value, s):
    """A current reading [A] quantised by the ADC of SensorParams ``s`` (clipped to its range)."""
    if s.adc_bits <= 0:
        return value
    lsb = 2.0 * s.adc_range_A / (1 << s.adc_bits)
    code = math.floor(value / lsb + 0.5)
    top = (1 << (s.adc_bits - 1)) - 1
    code = min(max(code, -top - 1), top)
    return code * lsb


@njit(cache=True, inline='always')
def sense_currents(i_a, i_b, i_c, s, seed, k):
    """Measured phase currents [A] of the true ones at sample k: gain and offset errors, Gaussian noise
    (seeded by ``seed`` and k) and ADC quantisation (SensorParams s). No state."""
    m_a = s.gain_a * i_a + s.offset_a_A
    m_b = s.gain_b * i_b + s.offset_b_A
    m_c = s.gain_c * i_c + s.offset_c_A
    if s.noise_std_A > 0.0:
        m_a += s.noise_std_A * gaussian(seed, k, 0)
        m_b += s.noise_std_A * gaussian(seed, k, 1)
        m_c += s.noise_std_A * gaussian(seed, k, 2)
    return _adc(m_a, s), _adc(m_b, s), _adc(m_c, s)


def incremental_inductances(machine, i_d_A=0.0, i_q_A=0.0):
    """(L_dh, L_qh, L_dqh) [H] at an operating point, from the inverse of Γ (Python helper)."""
    psi_d, psi_q = flux_from_current(machine, i_d_A, i_q_A)
    g_dd, g_qq, g_dq = incremental_inverse_inductance(psi_d, psi_q, machine)
    inv = np.linalg.inv(np.array([[g_dd, g_dq], [g_dq, g_qq]]))
    return inv[0, 0], inv[1, 1], inv[0, 1]


def flux_from_current(machine, i_d_A, i_q_A):
    """Invert current_from_flux by Newton iteration (Python helper for analysis and tests)."""
    psi = np.array([machine.psi_f_Wb + machine.L_d_H * i_d_A, machine.L_q_H * i_q_A])
    for _ in range(50):
        i_d, i_q = current_from_flux(psi[0], psi[1], machine)
        residual = np.array([i_d - i_d_A, i_q - i_q_A])
        g_dd, g_qq, g_dq = incremental_inverse_inductance(psi[0], psi[1], machine)
        psi -= np.linalg.solve(np.array([[g_dd, g_dq], [g_dq, g_qq]]), residual)
        if np.max(np.abs(residual)) < 1e-12:
            break
    return float(psi[0]), float(psi[1])


def saturation_saliency_angle(machine, i_d_A=0.0, i_q_A=0.0, saliency_sign=1.0):
    """Angle [rad, electrical] by which cross-saturation turns the HF saliency axis from d; with
    ``saliency_sign`` −1 (L_dh > L_qh) the axis of the smaller admittance is the one that starts on d."""
    psi_d, psi_q = flux_from_current(machine, i_d_A, i_q_A)
    g_dd, g_qq, g_dq = incremental_inverse_inductance(psi_d, psi_q, machine)
    return 0.5 * math.atan2(2.0 * saliency_sign * g_dq, saliency_sign * (g_dd - g_qq))
