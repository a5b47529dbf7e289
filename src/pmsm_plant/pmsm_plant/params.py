"""True (plant-side) parameters of the motor, its mechanics, the inverter and the current sensors.

Parameters are immutable ``NamedTuple``s: frozen like motulator's dataclasses, with SI units in the
field names, and passable unchanged into the numba kernels. ``PlantParams`` gathers what a period's
integration and sampling read; ``PlantInputs`` what a block of samples is driven by (kept apart from
the parameters and from the state, as motulator keeps them). What the drive knows of the motor (its
nameplate and commissioning record) lives in ``drive_common.motor``; the estimators and the controller never
read these.
"""
import math
from typing import NamedTuple

import numpy as np


class MachineParams(NamedTuple):
    """Electrical dq model of a PMSM with flux linkage as state (Szabó Eq. 1-3, Wang Eq. 1).

    Magnetics follow an algebraic saturation model (after Hinkkanen et al., "Sensorless
    self-commissioning of synchronous reluctance motors at standstill without rotor locking",
    IEEE TIA 2017), written as the gradient of a magnetic energy W(ψ_d, ψ_q) so that the incremental
    inductance matrix is symmetric (reciprocal cross-saturation):

        i_d = ψ_d/L_d + a_d ψ_d⁵ + (a_dq/2)|ψ_d|ψ_d ψ_q² − i_f
        i_q = ψ_q/L_q + a_q ψ_q³ + (a_dq/3)|ψ_d|³ ψ_q

    with i_f chosen so that i = 0 at ψ = (ψ_f, 0). With a_d = a_q = a_dq = 0 it is the linear model
    ψ_d = L_d i_d + ψ_f, ψ_q = L_q i_q. The PM flux itself saturates the d-axis iron through a_d
    (saturation saliency), and a_dq couples the axes (cross-saturation).
    """

    n_p: int
    """Pole pairs."""
    R_s_ohm: float
    """Stator resistance."""
    L_d_H: float
    """Unsaturated d-axis inductance."""
    L_q_H: float
    """Unsaturated q-axis inductance."""
    psi_f_Wb: float
    """Permanent-magnet flux linkage (amplitude-invariant scaling)."""
    a_d: float = 0.0
    """d-axis self-saturation coefficient [A/Wb⁵]."""
    a_q: float = 0.0
    """q-axis self-saturation coefficient [A/Wb³]."""
    a_dq: float = 0.0
    """Cross-saturation coefficient [A/Wb⁴]."""
    C_th_J_K: float = 0.0
    """Thermal capacity of the winding; 0: isothermal (R_s stays R_s_ohm). The first-order model:
    C_th dΔT/dt = 1.5 R_s(T) |i_αβ|² − ΔT/R_th, ΔT the rise above ambient (state WINDING_RISE)."""
    R_th_K_W: float = 1.0
    """Thermal resistance winding → ambient."""
    T_ambient_degC: float = 20.0
    """Ambient (and initial winding) temperature; R_s_ohm is the resistance at 20 °C."""


class MechanicsParams(NamedTuple):
    """Rigid shaft: J dω_m/dt = τ_e − τ_L − τ_stop − B ω_m (Szabó Eq. 4, with end stops: a spring-damper
    τ_stop = k (θ_m − θ_stop) + b ω_m while θ_m is beyond one)."""

    J_kgm2: float
    """Total inertia of rotor and coupled load."""
    B_Nms: float
    """Viscous friction coefficient."""
    stop_low_rad: float = -math.inf
    """The shaft's lower end stop [rad, mechanical] (−∞: none)."""
    stop_high_rad: float = math.inf
    """Its upper end stop [rad] (∞: none)."""
    stop_stiffness_Nm_rad: float = 0.0
    """The stops' spring k."""
    stop_damping_Nms_rad: float = 0.0
    """The stops' damper b."""


class InverterParams(NamedTuple):
    """Two-level voltage-source inverter, averaged over a switching period."""

    U_dc_V: float
    """DC-link voltage; the space-vector linear range is |u_αβ| ≤ U_dc/√3."""
    t_dead_s: float
    """Dead time; the average phase-voltage error is −(t_dead/T_s)·U_dc·sign(i)."""
    i_dead_A: float
    """Current scale of the smoothed sign tanh(i/i_dead) (switch-capacitance commutation)."""
    delay_periods: int
    """Delay from sample to applied command [periods]: 1 = a command computed from sample k is applied
    during period k+1; blocks of N samples add N − 1 (pmsm_plant.build)."""
    C_dc_F: float = math.inf
    """DC-link capacitance. The supply is U_dc_V behind a diode: it sources but cannot absorb, so the bus
    is U_dc_V or above, C dU/dt = −i_dc − i_brake while above (∞: a stiff bus, which never rises)."""
    R_brake_ohm: float = math.inf
    """Brake-chopper resistor across the link (∞: none)."""
    U_brake_on_V: float = math.inf
    """The chopper switches the resistor on above this bus voltage ..."""
    U_brake_off_V: float = math.inf
    """... and off again below this one (hysteresis)."""


class SensorParams(NamedTuple):
    """Phase-current sensing, sampled synchronously at the start of every control period."""

    noise_std_A: float
    offset_a_A: float
    offset_b_A: float
    offset_c_A: float
    gain_a: float
    gain_b: float
    gain_c: float
    adc_bits: int
    """0 disables quantisation."""
    adc_range_A: float
    """Full scale: readings are quantised over [−range, +range) and clip at its ends."""


IDEAL_SENSOR = SensorParams(noise_std_A=0.0, offset_a_A=0.0, offset_b_A=0.0, offset_c_A=0.0, gain_a=1.0, gain_b=1.0,
                            gain_c=1.0, adc_bits=0, adc_range_A=1.0)
"""Current sensors that read the true currents."""


class PlantParams(NamedTuple):
    """Everything the plant's kernels read that a run does not change (pmsm_plant.model)."""

    machine: MachineParams
    mechanics: MechanicsParams
    inverter: InverterParams
    sensor: SensorParams
    seed: int
    """Sensor-noise seed (pmsm_plant.model.gaussian)."""
    T_s_s: float
    """Control (sampling) period."""
    substeps: int
    """Runge-Kutta steps per period."""


class PlantInputs(NamedTuple):
    """What drives a block of samples (pmsm_plant.model.plant_block), per period indexed by the sample k
    that starts it."""

    load_Nm: np.ndarray
    """Load torque."""
    speed_rad_s: np.ndarray
    """The shaft's speed where ``imposed`` (dynamometer); otherwise not read."""
    imposed: bool
    """The shaft follows ``speed_rad_s`` instead of its torque balance."""
    release_k: int
    """A brake holds the shaft at rest in every period j < release_k (−1: no brake; model.NOT_RELEASED:
    held until further notice)."""
