"""The speed loop's stability margins, predicted from what the drive knows (docs/motors-and-control.md "The speed
loop's margin"): the speed PI, the current loop it commands (its PI on R_s + s·L_q behind the loop delay), the rotor
k_t/(J s + B), and the speed estimate it is fed: the estimator's tracking loop (TrackingLoop; ω̂ is the loop's
integrator, which follows the shaft's speed as (k_i s + k_a)·e^{−sτ} / (s³ + (k_p s² + k_i s + k_a)·e^{−sτ})) and
the controller's first-order speed filter. The open loop, cut at the speed error:

    L(jω) = (k_pω + k_iω/jω) · T_i(jω) · k_t/(J jω + B) · H_ω̂(jω) · F(jω).

The tracking loop's gains scale with its error's slope, which under load is the commissioned convergence slope F,
not one; the margins are the worst over the slopes the estimator states (TrackingLoop.slopes).
Its phase margin at the crossover and its gain margin where its phase reaches −180° say how far the loop rings: the
robot arm's speed loop in blocks of 10 at 10 kHz had 13° and 2.9 dB and hunted at 8.0 Hz (predicted crossover
7.6 Hz), its shaft's speed ±1 rad/s about its command. A small-signal model: it reads a type-3 loop's margins low
(1.5° where a joint's loop rang at 50 Hz without diverging). No rclpy."""
import math
from typing import NamedTuple

import numpy as np

SPEED_PHASE_MARGIN_DEG = 35.0
SPEED_GAIN_MARGIN_DB = 6.0
"""With 'rule' gains the speed loop's ω_n is the largest, at most the other rules', whose loop keeps these margins
(foc_controller.params): 45° halved the ripple in blocks again but slowed a rated load step's recovery past the
paper's (docs/motors-and-control.md "The speed loop's margin")."""
GENERIC_TRACKING_DAMPING = 0.9
"""An estimator that states its bandwidth but not its loop is taken as a type-2 loop of this damping without
delay: the mildest reading of its bandwidth."""
FREQUENCIES = np.logspace(-1.0, 5.0, 3000)
"""The grid [rad/s] margins are read on."""


class TrackingLoop(NamedTuple):
    """An estimator's angle-tracking loop as its speed estimate follows the shaft: gains k_p [1/s], k_i [1/s²], k_a
    [1/s³] on an error of unit slope (hf_estimator.tracking_loop.tracking_loop) and the delay of its error path
    ``delay_s`` [s] (the angle the error measures is this old). Under load the error's slope per radian of angle
    error is not one: an injecting estimator's falls to the commissioned convergence slope F at its q current
    (cross-saturation turns the saliency axis back as the rotor turns). ``slope_min`` and ``slope_max`` bound it
    over the currents the drive allows: each multiplies the three gains."""

    kp: float
    ki: float
    ka: float
    delay_s: float
    slope_min: float = 1.0
    slope_max: float = 1.0

    def slopes(self):
        """The slopes the speed loop keeps its margins at: the range's ends and one."""
        return tuple(sorted({self.slope_min, 1.0, self.slope_max}))

    def at_slope(self, slope):
        """This loop with its error's slope ``slope`` (its gains scaled by it) as a unit-slope loop."""
        return TrackingLoop(slope * self.kp, slope * self.ki, slope * self.ka, self.delay_s)


class SpeedEstimate(NamedTuple):
    """What the controller knows of the speed estimate it is fed: the estimator's tracking ``bandwidth_Hz`` (∞: a
    sensor) and its ``loop`` (None: not stated, then read as generic_tracking_loop at that bandwidth)."""

    bandwidth_Hz: float = math.inf
    loop: TrackingLoop | None = None

    def tracking_loop(self):
        """The TrackingLoop the speed loop's margins are read on (None: the estimate is the shaft's speed)."""
        return self.loop if self.loop is not None else generic_tracking_loop(self.bandwidth_Hz)


class SpeedLoopPlant(NamedTuple):
    """What the speed loop acts on: the q current loop's PI (kp [V/A], ki [V/(A·s)]) on R_s [Ω] and L_q [H] behind
    ``delay_s`` [s], the torque constant k_t [N·m/A], the rotor's J [kg·m²] and B [N·m·s], the speed estimate's
    ``tracking`` (None: the estimate is the shaft's speed) and the speed filter's per-sample gain at T_s [s]."""

    kp_q: float
    ki_q: float
    R_s_ohm: float
    L_q_H: float
    delay_s: float
    k_t_Nm_per_A: float
    J_kgm2: float
    B_Nms: float
    tracking: TrackingLoop | None
    speed_filter_gain: float
    T_s_s: float


class Margins(NamedTuple):
    crossover_rad_s: float
    phase_margin_deg: float
    gain_margin_db: float
    """∞ where the phase never reaches −180° on the grid."""


def generic_tracking_loop(bandwidth_Hz):
    """TrackingLoop of a type-2 loop at ω_n = 2π·bandwidth (GENERIC_TRACKING_DAMPING, no delay); None for ∞."""
    if not math.isfinite(bandwidth_Hz):
        return None
    omega_n = 2.0 * math.pi * bandwidth_Hz
    return TrackingLoop(2.0 * GENERIC_TRACKING_DAMPING * omega_n, omega_n ** 2, 0.0, 0.0)


def speed_estimate_response(tracking, omega):
    """ω̂/ω of ``tracking`` (TrackingLoop) at ``omega`` [rad/s, array]; 1 without a tracking loop."""
    if tracking is None:
        return np.ones_like(omega, dtype=complex)
    s = 1j * omega
    delay = np.exp(-s * tracking.delay_s)
    return (tracking.ki * s + tracking.ka) * delay / (s ** 3 + (tracking.kp * s * s + tracking.ki * s + tracking.ka)
                                                      * delay)


def open_loop_parts(plant, kp_speed, ki_speed, omega):
    """The factors of L(jω) (module docstring) at ``omega`` [rad/s, array]: the speed PI [A·s/rad, A/rad], the current
    loop, the rotor, the speed estimate, the speed filter; each starts near its own phase at low frequency."""
    s = 1j * omega
    current_pi = plant.kp_q + plant.ki_q / s
    forward = current_pi / (plant.L_q_H * s + plant.R_s_ohm) * np.exp(-s * plant.delay_s)
    g = plant.speed_filter_gain
    return (kp_speed + ki_speed / s, forward / (1.0 + forward),
            plant.k_t_Nm_per_A / (plant.J_kgm2 * s + plant.B_Nms), speed_estimate_response(plant.tracking, omega),
            g / (1.0 - (1.0 - g) * np.exp(-s * plant.T_s_s)))


def margins(plant, kp_speed, ki_speed):
    """Margins of the speed loop, the worst over its tracking loop's slopes (TrackingLoop.slopes): the smallest phase
    margin and the smallest gain margin, each with its own slope; the crossover of the slope whose phase margin is
    the smallest."""
    if plant.tracking is None:
        return margins_at_slope(plant, kp_speed, ki_speed)
    found = [margins_at_slope(plant._replace(tracking=plant.tracking.at_slope(slope)), kp_speed, ki_speed)
             for slope in plant.tracking.slopes()]
    worst = min(found, key=lambda m: m.phase_margin_deg)
    return worst._replace(gain_margin_db=min(m.gain_margin_db for m in found))


def margins_at_slope(plant, kp_speed, ki_speed):
    """Margins of the speed loop on its tracking loop as given (its gains at unit slope): its phase at the first
    crossover of |L| = 1 from above, its gain where its phase (the factors' phases, each unwrapped from low
    frequency) first falls to −180° past that crossover."""
    parts = open_loop_parts(plant, kp_speed, ki_speed, FREQUENCIES)
    magnitude = np.abs(np.prod(parts, axis=0))
    phase = sum(np.unwrap(np.angle(part)) for part in parts)
    below = np.nonzero(magnitude < 1.0)[0]
    if below.size == 0:
        return Margins(math.inf, -math.inf, -math.inf)
    i = below[0]
    past = i + np.nonzero(phase[i:] <= -math.pi)[0]
    gain_margin = -20.0 * math.log10(magnitude[past[0]]) if past.size else math.inf
    return Margins(float(FREQUENCIES[i]), 180.0 + math.degrees(phase[i]), gain_margin)
