"""What a robot's axis does when its commands stop (issue 54): a command older than ``timeout_s`` ramps the
speed reference to zero at ``deceleration_rad_s2`` and then holds the joint where it stopped, a position loop
on the estimated mechanical angle feeding the speed loop (ω* = k_θ (θ_hold − θ̂_m), within ±``hold_speed_rad_s``;
over the speed PI its integrator carries whatever load there is, so the hold has no steady-state error);
older than ``hold_timeout_s``, or once stopped where the joint has a ``brake``, zero torque. A fresh command
takes over at once. A position command (a homed joint's, foc_controller.position) drives the same position loop
to its target, its velocity a feed-forward, within ±``velocity_limit_rad_s``; older than ``timeout_s`` the joint is
held at that target. No rclpy: the controller node calls it once per sample or block."""
import math
from dataclasses import dataclass

from .speed_command import commanded_speed, position_command, speed_command

FOLLOWING, STOPPING, HOLDING, RELEASED = "following", "stopping", "holding", "released"
HOLD_GAIN_PER_SPEED_ZERO = 0.25
"""k_θ as a share of the speed PI's zero ki/kp [1/s]: the position loop well inside the speed loop (for the
usual ζ = 1 gains the zero is half the speed loop's bandwidth, so k_θ is an eighth of it)."""
STOP_TIME_S = 0.2
"""The default ramp takes the speed limit (or the rated speed) to zero in this time."""


@dataclass(frozen=True)
class HoldSettings:
    """``timeout_s`` [s] (0: commands never expire), ``hold_timeout_s`` [s] (∞: hold for good), ``brake``,
    ``deceleration_rad_s2`` of the ramp, the position loop's ``gain_per_s`` k_θ and its speed bound
    ``hold_speed_rad_s`` while holding, ``velocity_limit_rad_s`` while following a position command."""

    timeout_s: float
    hold_timeout_s: float
    brake: bool
    deceleration_rad_s2: float
    gain_per_s: float
    hold_speed_rad_s: float
    velocity_limit_rad_s: float = math.inf


class CommandHold:
    """The speed reference and torque feed-forward an axis follows, from its last command and its age."""

    def __init__(self, settings, now_s):
        self.settings = settings
        self.mode = FOLLOWING
        self.omega_m_ref, self.tau_feedforward = 0.0, 0.0
        self.commanded_at = now_s
        self.ramp = 0.0
        self.theta_hold = math.nan
        self.theta_ref = math.nan
        """The position command's target [rad, the estimated mechanical angle's], NaN: a speed command."""
        self.speed = 0.0
        """The last speed reference ``reference`` gave [rad/s]."""
        self.timeouts = 0

    def command(self, now_s, omega_m_ref=None, tau_feedforward=None, theta_ref=None):
        """A fresh command [rad/s, N·m] (None: the last one's); followed from now on. With ``theta_ref`` [rad]
        the position loop's target, ``omega_m_ref`` its feed-forward (None: 0); a command without one is a speed
        command."""
        if theta_ref is not None:
            self.omega_m_ref = 0.0
        self.theta_ref = math.nan if theta_ref is None else theta_ref
        if omega_m_ref is not None:
            self.omega_m_ref = omega_m_ref
        if tau_feedforward is not None:
            self.tau_feedforward = tau_feedforward
        self.commanded_at = now_s
        self.mode = FOLLOWING

    def age_s(self, now_s):
        return now_s - self.commanded_at

    def reference(self, now_s, dt_s, theta_m_hat):
        """(ω*_m [rad/s], τ_ff [N·m], torque allowed) for the next ``dt_s`` [s] of samples, at ``now_s`` [s],
        the estimated mechanical angle being ``theta_m_hat`` [rad]: ``command_now``'s command followed from the last
        reference given."""
        command, tau_feedforward, torque = self.command_now(now_s, dt_s, theta_m_hat)
        self.speed = commanded_speed(command, self.speed, theta_m_hat, dt_s)
        return self.speed, tau_feedforward, torque

    def command_now(self, now_s, dt_s, theta_m_hat):
        """(the speed command to follow for the next ``dt_s`` [s] of samples (foc_controller.speed_command), τ_ff
        [N·m], torque allowed), at ``now_s`` [s], the estimated mechanical angle being ``theta_m_hat`` [rad]."""
        s = self.settings
        age = self.age_s(now_s)
        positioned = not math.isnan(self.theta_ref)
        if s.timeout_s <= 0.0 or age <= s.timeout_s:
            if positioned:
                return position_command(self.theta_ref, self.omega_m_ref, s.gain_per_s,
                                        s.velocity_limit_rad_s), self.tau_feedforward, True
            return speed_command(self.omega_m_ref), self.tau_feedforward, True
        if self.mode == FOLLOWING and positioned:
            self.mode, self.theta_hold = (RELEASED if s.brake else HOLDING), self.theta_ref
            self.timeouts += 1
        if self.mode == FOLLOWING:
            self.mode, self.ramp = STOPPING, self.omega_m_ref
            self.timeouts += 1
        if self.mode == STOPPING:
            self.ramp = commanded_speed(speed_command(0.0, s.deceleration_rad_s2), self.ramp, theta_m_hat, dt_s)
            if self.ramp == 0.0:
                self.mode, self.theta_hold = (RELEASED if s.brake else HOLDING), theta_m_hat
            return speed_command(0.0, s.deceleration_rad_s2), self.tau_feedforward, True
        if self.mode == HOLDING and age > s.hold_timeout_s:
            self.mode = RELEASED
        if self.mode == RELEASED:
            return speed_command(0.0), 0.0, False
        return position_command(self.theta_hold, 0.0, s.gain_per_s, s.hold_speed_rad_s), self.tau_feedforward, True
