"""Speed supervision: does the shaft follow its command? Judged from what the drive knows (its speed
estimate, its reference and its own current reference), never the plant (docs/motors-and-control.md
"Supervision"). One kernel, sample by sample, for the controller node (on /diagnostics) and for a
run's log (`drive run/launch/bridge --json`, exit code 6).

A drive whose load exceeds what it may deliver (its current limit, the sensorless one included) is
dragged along by the load while its angle estimate may stay locked. Over samples where the estimator
tracks:
- the speed error e = ω*_m − ω̂_m, low-passed over FILTER_S, beyond SPEED_TOLERANCE_PER_RATED of rated
  speed plus FOLLOW_TOLERANCE of |ω*|, for longer than PERSIST_S: "dragged backwards" where ω̂ runs
  against a non-zero ω*, "stalled" where |ω̂| stays within the tolerance, else "not following";
- where the controller ramps its speed reference (ControllerParams.speed_ramp_rad_s2), e is taken against the
  command slewed the same way (drive_common.math.filters.slew, from the shaft's estimated speed where tracking
  starts): a commanded step the drive takes at its stated slope is followed, not a fault;
- the current reference's magnitude |i*| at LIMIT_SHARE of the current limit for longer than
  CURRENT_LIMIT_PERSIST_S: "at the current limit" (a speed ramp at full torque lasts a few tenths of a
  second; a held overload does not end).
Each fault names the torque the drive holds there (its stated sensorless torque limit,
drive_common.motor.torque_limit) where it is given: a load beyond it is held at it, the angle kept.
"""
import math

import numpy as np
from numba import njit

from drive_common.math.filters import slew

FILTER_S = 0.02
SPEED_TOLERANCE_PER_RATED = 0.05
FOLLOW_TOLERANCE = 0.25
LIMIT_SHARE = 0.99
PERSIST_S = 0.2
"""How long a speed fault must last before it is one (a speed step's transient settles well within it)."""
CURRENT_LIMIT_PERSIST_S = 1.0
"""How long the current reference may sit at the limit (full-torque ramps of the shipped scenarios: ≤ 0.4 s)."""
TRACKING = 3.0
KINDS = ("dragged backwards", "stalled", "not following", "at the current limit")

SMOOTH, RAMPED, COUNTS = 0, 1, 2
STATE_SIZE = COUNTS + len(KINDS)
GAIN, TOLERANCE, FOLLOW, N_P, LIMIT, NEED_SPEED, NEED_LIMIT, RAMP_STEP = range(8)


@njit(cache=True)
def supervision_step(s, p, omega_m_ref, omega_e_hat, i_q_ref, state):
    """One sample: update the supervision state ``s`` (params ``p``); return a bit mask, bit i: fault
    KINDS[i] raised at this sample, bit i + 4: fault KINDS[i] ended at this sample."""
    omega_hat = omega_e_hat / p[N_P]
    tracking = state == TRACKING
    s[RAMPED] = slew(s[RAMPED], omega_m_ref, p[RAMP_STEP]) if tracking else omega_hat
    if tracking:
        omega_m_ref = s[RAMPED]
    s[SMOOTH] += p[GAIN] * (omega_m_ref - omega_hat - s[SMOOTH])
    away = tracking and abs(s[SMOOTH]) > p[TOLERANCE] + p[FOLLOW] * abs(omega_m_ref)
    moving = abs(omega_hat) > p[TOLERANCE]
    backwards = away and moving and omega_m_ref != 0.0 and omega_hat * omega_m_ref < 0.0
    stalled = away and not moving
    conditions = (backwards, stalled, away and not backwards and not stalled,
                  tracking and abs(i_q_ref) >= p[LIMIT])
    events = 0
    for i in range(4):
        need = p[NEED_LIMIT] if i == 3 else p[NEED_SPEED]
        if conditions[i]:
            s[COUNTS + i] += 1.0
            if s[COUNTS + i] == need:
                events |= 1 << i
        else:
            if s[COUNTS + i] >= need:
                events |= 1 << (i + 4)
            s[COUNTS + i] = 0.0
    return events


@njit(cache=True)
def supervision_block(s, p, omega_m_ref, omega_e_hat, i_q_ref, state, events):
    """supervision_step over arrays of samples; ``events[i]`` its bit mask of sample i."""
    for i in range(len(omega_m_ref)):
        events[i] = supervision_step(s, p, omega_m_ref[i], omega_e_hat[i], i_q_ref[i], state[i])


class SpeedSupervisor:
    """The supervision of one drive: n_p, rated speed [rad/s mech.], current limit [A], sample period [s], the line
    stating its torque limit ("": none stated), its speed reference's ramp [rad/s² mech.; ∞: none]. ``update`` takes
    the samples from ``k0`` on (the current reference as its magnitude) and returns the faults raised in them;
    ``faults`` holds every fault, {kind, start_s, duration_s (None while it lasts), speed_reference_rad_s,
    speed_estimate_rad_s, torque_limit}."""

    def __init__(self, n_p, rated_speed_rad_s, current_limit_A, T_s, torque_limit="", speed_ramp_rad_s2=math.inf):
        self.T_s = T_s
        self.torque_limit = torque_limit
        self.params = np.array([1.0 - math.exp(-T_s / FILTER_S), SPEED_TOLERANCE_PER_RATED * rated_speed_rad_s,
                                FOLLOW_TOLERANCE, n_p, LIMIT_SHARE * current_limit_A,
                                max(1, round(PERSIST_S / T_s)), max(1, round(CURRENT_LIMIT_PERSIST_S / T_s)),
                                speed_ramp_rad_s2 * T_s])
        self.state = np.zeros(STATE_SIZE)
        self.faults = []
        self.open = {}

    def warm_up(self):
        """Load the block kernel before the first sample (a first call from Python loads it from numba's
        cache, milliseconds the first block cannot spare behind a paced inverter)."""
        one = np.zeros(1)
        supervision_block(self.state.copy(), self.params, one, one, one, one, np.zeros(1, dtype=np.int64))

    def update(self, k0, omega_m_ref, omega_e_hat, i_q_ref, state):
        """Samples k0, k0+1, … (arrays): the faults raised in them."""
        arrays = [np.ascontiguousarray(a, dtype=float) for a in (omega_m_ref, omega_e_hat, i_q_ref, state)]
        events = np.zeros(len(arrays[0]), dtype=np.int64)
        supervision_block(self.state, self.params, *arrays, events)
        raised = []
        for i in np.nonzero(events)[0]:
            raised += self._events(k0 + int(i), int(events[i]), arrays[0][i], arrays[1][i])
        return raised

    def step(self, k, omega_m_ref, omega_e_hat, i_q_ref, state):
        """Sample k (scalars): the faults raised at it."""
        events = supervision_step(self.state, self.params, omega_m_ref, omega_e_hat, i_q_ref, state)
        return self._events(k, events, omega_m_ref, omega_e_hat) if events else []

    def _events(self, k, events, omega_m_ref, omega_e_hat):
        raised = []
        for i, kind in enumerate(KINDS):
            if events >> (i + 4) & 1 and kind in self.open:
                fault = self.open.pop(kind)
                fault["duration_s"] = k * self.T_s - fault["start_s"]
            if events >> i & 1:
                need = self.params[NEED_LIMIT if i == 3 else NEED_SPEED]
                fault = {"kind": kind, "start_s": (k - need + 1) * self.T_s, "duration_s": None,
                         "speed_reference_rad_s": float(omega_m_ref),
                         "speed_estimate_rad_s": float(omega_e_hat / self.params[N_P]),
                         "torque_limit": self.torque_limit}
                self.open[kind] = fault
                self.faults.append(fault)
                raised.append(fault)
        return raised

    def finish(self, k_end):
        """The run ended before sample ``k_end``: faults still lasting end there."""
        for fault in self.open.values():
            fault["duration_s"] = k_end * self.T_s - fault["start_s"]
        self.open = {}


def speed_supervision(t_s, omega_m_ref, omega_e_hat, current_ref, state, drive):
    """Faults of a run's samples (arrays per sample: time [s], mechanical speed reference [rad/s],
    electrical speed estimate [rad/s], current reference magnitude [A], estimator state code), in order;
    ``drive``: (n_p, rated speed [rad/s mech.], current limit [A], the torque limit's line, the speed reference's
    ramp [rad/s² mech.; ∞: none])."""
    if len(t_s) < 2:
        return []
    T_s = float(t_s[1] - t_s[0])
    k0 = int(round(t_s[0] / T_s))
    n_p, rated_speed_rad_s, current_limit_A, torque_limit, ramp = drive
    supervisor = SpeedSupervisor(n_p, rated_speed_rad_s, current_limit_A, T_s, torque_limit, ramp)
    supervisor.update(k0, omega_m_ref, omega_e_hat, current_ref, state)
    supervisor.finish(k0 + len(t_s))
    return sorted(supervisor.faults, key=lambda f: f["start_s"])


def fault_line(fault):
    """One line for a supervision fault."""
    lasting = "" if fault["duration_s"] is None else f" for {fault['duration_s']:.3f} s"
    held = f": the drive holds its {fault['torque_limit']}" if fault.get("torque_limit") else ""
    return (f"{fault['kind']} from {fault['start_s']:.3f} s{lasting} "
            f"(ω* {fault['speed_reference_rad_s']:+.2f}, ω̂ {fault['speed_estimate_rad_s']:+.2f} rad/s){held}")
