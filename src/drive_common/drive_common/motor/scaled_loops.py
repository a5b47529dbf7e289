"""Loops scaled to the motor: the drive's tracking loop, carrier, amplitude and speed loop derived from
what it knows (nameplate, inverter, sampling period), docs/motors-and-control.md "Loops scaled to the
motor".

The stress on an angle tracker is the rotor's acceleration: a rated-torque load step accelerates the rotor
at a_e = n_p·τ_rated/J [rad/s², electrical] until the speed loop answers, and a type-2 loop lags a constant
acceleration by a_e/ω_n². The rule:

1. Tracking (ours' PLL): ω_n = √(a_e / ACCELERATION_LAG_RAD), at least MIN_TRACKING_HZ, at most the
   carrier's f_h / CARRIER_PER_TRACKING (the fit window of two carrier periods delays the error).
2. Carrier: f_s / SAMPLES_PER_CARRIER, raised to CARRIER_PER_TRACKING × the tracking bandwidth the motor
   needs, up to f_s / MIN_SAMPLES_PER_CARRIER.
   Where that acceleration, not the minimum, sets the bandwidth, ours' loop is type 3 when its signal has
   the noise margin (hf_estimator.injection_frame.tracking_loop_type).
3. Speed loop: ω_s = √(a_e / EXCURSION_RAD) (a load step then turns the rotor by about EXCURSION_RAD
   electrical before the loop holds it), at least MIN_SPEED_BANDWIDTH_RAD_S; the controller keeps it a
   cascade step below the tracking loop and the current loops, and within its margins on the estimator's own
   loop (foc_controller.params, foc_controller.speed_margin).
4. Speed ramp: where ours' injection leads over the whole speed range, the speed reference's slope is held to
   the acceleration its tracking loop follows within SPEED_RAMP_LAG_RAD, ω_n²·SPEED_RAMP_LAG_RAD (electrical;
   tracked_acceleration_e_rad_s2): a speed step would otherwise drive the speed loop to the current limit and
   accelerate the rotor far beyond what the loop was sized for (a rated-torque step), as long as the step lasts.
5. Amplitude: the HF current ripple U_h·Σ/ω_h at HF_RIPPLE_PER_RATED of rated current (nameplate Σ), at
   most HF_VOLTAGE_PER_LINEAR of the linear voltage range U_dc/√3; a requested amplitude is held to the
   same cap.

The constants are set so that the two shipped motors keep the values they were tuned with (18 Hz,
40 rad/s); where J is not known the rule falls back to those.
"""
import math
from typing import NamedTuple

ACCELERATION_LAG_RAD = 0.25
MIN_TRACKING_HZ = 18.0
CARRIER_PER_TRACKING = 25.0
SAMPLES_PER_CARRIER = 10
MIN_SAMPLES_PER_CARRIER = 5
EXCURSION_RAD = 2.0
MIN_SPEED_BANDWIDTH_RAD_S = 40.0
SPEED_RAMP_LAG_RAD = 0.05
"""The tracking lag a ramped speed reference may cost [rad, electrical]: a third of ours' peak target (0.15 rad),
as the speed PI following a ramp's start accelerates the rotor for a moment at about twice the ramp's slope, and
the noise takes the rest (on drawn motors a lag budget of 0.075 rad still peaked at 0.141 rad)."""
HF_RIPPLE_PER_RATED = 0.2
HF_VOLTAGE_PER_LINEAR = 0.8


class ScaledLoops(NamedTuple):
    """The drive's loops for one motor (rule above); ``notes``: what the drive says of them."""

    acceleration_e_rad_s2: float
    """a_e = n_p·τ_rated/J (NaN where J is not known)."""
    tracking_bandwidth_Hz: float
    injection_frequency_Hz: float
    injection_amplitude_V: float
    speed_bandwidth_rad_s: float
    amplitude_cap_V: float
    """The largest HF amplitude the bus allows (HF_VOLTAGE_PER_LINEAR · U_dc/√3; ∞ where U_dc is unknown)."""
    largest_tracked_load_step_per_rated: float
    """The load step (per rated torque) whose acceleration the tracking loop still follows within
    ACCELERATION_LAG_RAD (∞ where J is not known)."""
    acceleration_limited: bool
    """The rotor's acceleration, not MIN_TRACKING_HZ, sets the tracking bandwidth (ours may then take a
    type-3 loop, which follows a constant acceleration without lag)."""
    notes: tuple


def scaled_loops(nameplate, inverter, T_s):
    """ScaledLoops for a motor with this ``nameplate`` on ``inverter`` (InverterRating) sampled every T_s."""
    f_s = 1.0 / T_s
    notes = []
    a_e = nameplate.n_p * nameplate.rated_torque_Nm / nameplate.J_kgm2
    if not math.isfinite(a_e) or a_e <= 0.0:
        a_e = math.nan
        notes.append("J unknown: tracking and speed loops at their defaults (18 Hz, 40 rad/s); give J_kgm2 or "
                     "let `drive commission` measure it")
    wanted_Hz = math.sqrt(a_e / ACCELERATION_LAG_RAD) / (2.0 * math.pi) if math.isfinite(a_e) else 0.0
    tracking_Hz = max(MIN_TRACKING_HZ, wanted_Hz)
    injection_frequency_Hz = min(max(f_s / SAMPLES_PER_CARRIER, CARRIER_PER_TRACKING * tracking_Hz),
                                 f_s / MIN_SAMPLES_PER_CARRIER)
    tracking_Hz = min(tracking_Hz, injection_frequency_Hz / CARRIER_PER_TRACKING)
    tracked_step = math.inf
    if wanted_Hz > tracking_Hz:
        tracked_step = (2.0 * math.pi * tracking_Hz) ** 2 * ACCELERATION_LAG_RAD / a_e
        notes.append(f"a rated-torque step accelerates this rotor at {a_e:.3g} rad/s² (electrical): tracking "
                     f"needs {wanted_Hz:.0f} Hz, the carrier allows {tracking_Hz:.0f} Hz; load steps above "
                     f"{tracked_step:.2f} × rated torque may outrun it (faster sampling raises the limit)")
    speed = MIN_SPEED_BANDWIDTH_RAD_S
    if math.isfinite(a_e):
        speed = max(speed, math.sqrt(a_e / EXCURSION_RAD))
    cap = HF_VOLTAGE_PER_LINEAR * inverter.U_dc_V / math.sqrt(3.0)
    sigma = 0.5 * (1.0 / nameplate.L_d_H + 1.0 / nameplate.L_q_H)
    amplitude = min(HF_RIPPLE_PER_RATED * nameplate.rated_current_A * 2.0 * math.pi * injection_frequency_Hz / sigma,
                    cap)
    return ScaledLoops(a_e, tracking_Hz, injection_frequency_Hz, amplitude, speed, cap, tracked_step,
                       wanted_Hz > MIN_TRACKING_HZ, tuple(notes))


def tracked_acceleration_e_rad_s2(tracking_bandwidth_Hz):
    """The electrical acceleration [rad/s²] a type-2 tracking loop of ``tracking_bandwidth_Hz`` (its ω_n / 2π)
    follows within SPEED_RAMP_LAG_RAD (its lag a_e/ω_n²); ∞ for a loop without a bandwidth (a sensor)."""
    if not math.isfinite(tracking_bandwidth_Hz):
        return math.inf
    return (2.0 * math.pi * tracking_bandwidth_Hz) ** 2 * SPEED_RAMP_LAG_RAD
