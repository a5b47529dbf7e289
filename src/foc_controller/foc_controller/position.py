"""A robot joint's position (issue 54): homing, then a position loop on the estimated mechanical angle.

Sensorless, the mechanical angle is known only up to the start-up's guess: HF saliency gives the electrical angle
modulo π and the magnet's polarity modulo 2π, so a rotor of n_p pole pairs may sit at any of n_p mechanical angles
the drive cannot tell apart. Homing gives the joint its zero: against a hard stop (the joint driven slowly,
``direction`` × ``speed_rad_s`` reached on a ramp whose acceleration takes a quarter of that current at most, until
it has stalled (|ω̂_m| below half the search speed) with the current that pushes it, i_q in the direction of travel,
above ``current_A`` for ``dwell_s``: the stop; the joint's zero is the stop + ``offset_rad``, and the joint backs off
``backoff_rad`` from it) or at an index pulse (driven the same way until the inverter reports its index input: the
joint's zero is the index + ``offset_rad``). Then the joint's position is θ̂_m − θ_zero, and a position command
θ* drives ω* = ω_ff + k_θ (θ_zero + θ* − θ̂_m) within the speed limit into the speed loop, whose integrator
carries the load (no steady-state error); k_θ as the command hold's (command_hold.HOLD_GAIN_PER_SPEED_ZERO). No
rclpy: the controller node calls it once per sample or block, in the motor's sign.
"""
import math
from dataclasses import dataclass

from .speed_command import commanded_speed, position_command, speed_command

HARD_STOP, INDEX = "hard_stop", "index"
HOMING_METHODS = (HARD_STOP, INDEX)
NOT_HOMED, SEEKING, BACKING_OFF, HOMED, FAILED = "not_homed", "seeking", "backing_off", "homed", "failed"
LOST = "lost"
"""The estimator re-found its angle (a lost lock, a new start-up): the electrical angle again, the mechanical one
only modulo 2π/n_p, so the zero is gone; the joint is not homed again by itself (it would drive to its stop
unasked): `~/home` homes it."""
BACKED_OFF_WITHIN_RAD = 0.05
"""Backing off ends once the estimated angle is this close to its target [rad]."""
RAMP_CURRENT_SHARE = 0.25
"""The search's acceleration takes at most this share of the stop's current (J a = share k_t i_stop): its current
never reads as the stop."""
STALLED_SPEED_SHARE = 0.5
"""The shaft has stalled below this share of the search speed."""


def search_acceleration(J_kgm2, k_t_Nm_per_A, current_A):
    """The search's ramp [rad/s²] for a shaft of inertia ``J_kgm2`` and torque constant ``k_t_Nm_per_A`` whose stop
    is found at ``current_A`` [A] (RAMP_CURRENT_SHARE)."""
    return RAMP_CURRENT_SHARE * k_t_Nm_per_A * current_A / J_kgm2


@dataclass(frozen=True)
class HomingSettings:
    """How a joint finds its zero: ``method`` (hard_stop or index), ``direction`` (±1, the motor's sign) and
    ``speed_rad_s`` of the search, the stop's ``current_A`` (|i_q| in the direction of travel, held ``dwell_s``
    [s]), the joint's zero ``offset_rad`` from the stop or index, how far ``backoff_rad`` the joint backs off
    from the stop, and ``timeout_s`` [s] of the search."""

    method: str
    direction: float
    speed_rad_s: float
    current_A: float = math.inf
    offset_rad: float = 0.0
    backoff_rad: float = 0.2
    dwell_s: float = 0.02
    timeout_s: float = 30.0


def position_speed(theta_ref, omega_ff, theta_m_hat, gain_per_s, limit_rad_s):
    """The speed reference ω* [rad/s] of the position loop: ω_ff + k_θ (θ* − θ̂_m) within ±``limit_rad_s``
    (angles [rad], ``gain_per_s`` k_θ [1/s], feed-forward ω_ff [rad/s])."""
    return commanded_speed(position_command(theta_ref, omega_ff, gain_per_s, limit_rad_s), 0.0, theta_m_hat, 0.0)


class Homing:
    """One joint's homing and its zero: ``start`` it, then ``reference`` each block until ``state`` is HOMED (the
    zero ``theta_zero`` known) or FAILED (``reason``)."""

    def __init__(self, settings, gain_per_s, limit_rad_s, acceleration_rad_s2):
        """``settings``: HomingSettings; the position loop's ``gain_per_s`` k_θ [1/s] and speed bound
        ``limit_rad_s`` (for the back-off); the search's ramp ``acceleration_rad_s2`` (search_acceleration)."""
        self.settings, self.gain_per_s, self.limit_rad_s = settings, gain_per_s, limit_rad_s
        self.acceleration_rad_s2 = acceleration_rad_s2
        self.search_speed = 0.0
        self.state, self.reason = NOT_HOMED, ""
        self.theta_zero = self.theta_found = self.target = math.nan
        self.elapsed_s = self.pushed_s = 0.0
        self.index_count = None

    @property
    def homed(self):
        return self.state == HOMED

    @property
    def active(self):
        return self.state in (SEEKING, BACKING_OFF)

    def start(self):
        """Search from now (again, where it had homed or failed)."""
        self.state, self.reason = SEEKING, ""
        self.theta_zero = self.theta_found = self.target = math.nan
        self.elapsed_s = self.pushed_s = self.search_speed = 0.0
        self.index_count = None

    def fail(self, why):
        """Homing failed (``why``: one line): FAILED until started again."""
        self.state, self.reason = FAILED, why
        self.theta_zero = self.theta_found = self.target = math.nan

    def lose(self, why):
        """The zero lost (``why``: one line): LOST until started again."""
        if self.state in (NOT_HOMED, FAILED, LOST):
            return
        self.state, self.reason = LOST, f"{why}: the homed zero is lost (home again: ~/home)"
        self.theta_zero = self.theta_found = self.target = math.nan

    def position(self, theta_m_hat):
        """The joint's position [rad] at the estimated mechanical angle ``theta_m_hat`` [rad] (NaN: its zero not
        found yet)."""
        return theta_m_hat - self.theta_zero

    def reference(self, dt_s, estimate, i_q_A, index_count=0):
        """The speed reference ω* [rad/s] for the next ``dt_s`` [s] of samples, the estimated mechanical angle and
        speed being ``estimate`` (θ̂_m [rad], ω̂_m [rad/s]), the measured q current ``i_q_A`` [A] (hard_stop) and
        the inverter's count of index pulses ``index_count`` (index); 0 once failed: ``command_now``'s command
        followed from the last reference given (0 at the search's start)."""
        command = self.command_now(dt_s, estimate, i_q_A, index_count)
        self.search_speed = commanded_speed(command, self.search_speed, estimate[0], dt_s)
        return self.search_speed

    def command_now(self, dt_s, estimate, i_q_A, index_count=0):
        """The speed command (foc_controller.speed_command) for the next ``dt_s`` [s] of samples, as ``reference``
        takes its arguments: the search's speed reached at its ramp, the back-off's position loop, else zero."""
        s = self.settings
        theta_m_hat, omega_m_hat = estimate
        if self.state == SEEKING:
            self.elapsed_s += dt_s
            if s.method == HARD_STOP:
                stalled = abs(omega_m_hat) < STALLED_SPEED_SHARE * s.speed_rad_s
                pushing = stalled and s.direction * i_q_A >= s.current_A
                self.pushed_s = self.pushed_s + dt_s if pushing else 0.0
                found = self.pushed_s >= s.dwell_s
            else:
                found = self.index_count is not None and index_count != self.index_count
                self.index_count = index_count
            if found:
                self.found(theta_m_hat)
            elif self.elapsed_s > s.timeout_s:
                self.state, self.reason = FAILED, (f"no {'stop' if s.method == HARD_STOP else 'index'} found "
                                                   f"in {s.timeout_s:g} s")
            else:
                return speed_command(s.direction * s.speed_rad_s, self.acceleration_rad_s2)
        if self.state == BACKING_OFF:
            if abs(self.target - theta_m_hat) <= BACKED_OFF_WITHIN_RAD:
                self.state = HOMED
            return position_command(self.target, 0.0, self.gain_per_s, self.limit_rad_s)
        return speed_command(0.0)

    def found(self, theta_m_hat):
        """The stop or the index at ``theta_m_hat`` [rad]: the zero set, the back-off begun (at an index, the
        joint held where it is)."""
        s = self.settings
        self.theta_found = theta_m_hat
        self.theta_zero = theta_m_hat + s.offset_rad
        backoff = s.backoff_rad if s.method == HARD_STOP else 0.0
        self.target = theta_m_hat - s.direction * backoff
        self.state = BACKING_OFF
