"""The standstill commissioning procedure as a per-sample core (docs/commissioning.md): measured phase
currents in, the voltage command for the next period out, nothing else. The one-process plant, the
ROS node and the bridge host all call ``step`` once per sample; the shaft must be held (a brake).

Segments, in order, each a fixed number of samples (so a host knows the length before it starts):
1. zero voltage: the sensor offsets;
2. DC currents along the six phase axes at two levels (a PI current loop in the stationary frame):
   the sensors' relative gains (the phase currents sum to zero), then R_s and the dead-time voltage;
3. HF rotating voltage at zero current: Γ, the saliency axis (mod π), L_dh and L_qh;
4. ± current with HF along both axes of Γ: the d axis and the magnet's polarity from the saturation
   asymmetry of the inductance (the magnet's axis saturates; L_dh > L_qh is then recognised too);
5. a grid of q currents up to the current limit (or the largest the bus drives), each at i_d = −Δ, 0, +Δ,
   with HF: the saliency-axis shift δ(i_q) and the convergence slope F(i_q) = 1 + i_q·∂δ/∂i_d from one
   smooth surface fitted to all the points (identification.saliency_surface: the weak saliency of an SPMSM
   makes each point's angle noisy);
6. zero voltage.

Every test current is checked against the bus before it is applied (the voltage it needs in steady state,
R_s·I plus the HF amplitude and the dead-time voltage, within BUS_HEADROOM of the modulation limit U_dc/√3:
the nameplate's R_s before the DC points, the measured one after) and after (each segment's mean current
within REACHED_SHARE of its reference): a DC point the bus cannot drive is refused (CommissioningError),
before any current where the nameplate predicts it; the polarity current and the table's top are scaled
down to what the bus drives, and ``conditions()["scaled"]`` says so.
"""
import math
from typing import NamedTuple

import numpy as np

from drive_common.contract.errors import DriveError
from drive_common.contract.settings import number
from drive_common.math.dead_time import SMOOTHING_PER_RATED_CURRENT, dead_time_direction
from drive_common.math.frames import SQRT3, clarke
from drive_common.motor.commissioning import MIN_SALIENCY_RATIO, Commissioning

from .identification import (
    admittance,
    axis_shift,
    in_frame,
    relative_gains,
    resistance_and_dead_time,
    saliency_axis,
    saliency_ratio_of,
    saliency_surface,
)

METHOD = "standstill_tests"
"""How the record was obtained, as written in its file."""
DEFAULTS = {"injection_frequency_Hz": 1000.0, "hf_current_fraction": 0.15, "dc_levels": (0.5, 1.0),
            "current_bandwidth_Hz": 100.0, "limit_margin": 0.97, "d_sweep_fraction": 0.2, "q_points": 9,
            "polarity_margin": 0.005}
"""injection_frequency_Hz: the HF carrier (sample-synchronous); hf_current_fraction: its current amplitude per
rated current (by the nameplate inductance); dc_levels: DC points per rated current; limit_margin: the
peak current stays below this fraction of the current limit; d_sweep_fraction: Δ per rated current;
q_points: the q-current grid (odd); polarity_margin: the relative L_dh asymmetry that decides polarity."""
SAMPLES = {"offsets": (30, 1000), "dc": (150, 100), "hf_zero": (100, 500), "polarity": (100, 300),
           "table": (60, 420), "end": (0, 20)}
"""(settle, measure) samples of each kind of segment."""
RAMP_SAMPLES = 40
"""A reference change is ramped over this many samples (no overshoot past the current limit)."""
TABLE_POINTS = 65
"""The record's tables sample the fitted surface on this many currents (the drive interpolates them)."""
BUS_HEADROOM = 0.95
"""A test current is reachable where the steady voltage it needs stays within this share of the modulation
limit U_dc/√3 (the rest: the current loop's headroom for noise and its integrator)."""
MIN_HF_SHARE = 0.25
"""The HF carrier's amplitude is lowered where the bus leaves it too little room beside the rated current's
R_s·I (its current ripple, and so the admittance's signal, shrinks with it), down to this share of its own."""
MIN_POLARITY_SHARE = 0.5
"""The polarity test runs at rated current, or at what the bus drives down to this share of it (the saturation
asymmetry it measures shrinks with the current); below, commissioning is refused."""
REACHED_SHARE = 0.95
"""A segment's mean current must reach this share of its reference where the voltage stood at BUS_HEADROOM of its
limit or more; less: the bus could not drive it."""
DEAD_TIME_AB = 4.0 / 3.0
"""The dead-time voltage per phase seen in αβ at most (amplitude-invariant Clarke)."""
HF_PER_DEAD_TIME = 5.0
"""The HF carrier's amplitude is at least this many times the measured dead-time voltage in αβ (see
CommissioningProcedure._clear_of_dead_time), ..."""
MAX_HF_CURRENT_FRACTION = 0.3
"""... its current ripple at most this share of rated current (the most the setting hf_current_fraction allows)."""


class Segment(NamedTuple):
    kind: str
    i_ref_ab: tuple
    """Current reference (α, β) [A], or None: zero voltage, no current loop."""
    hf: bool
    settle: int
    measure: int


class CommissioningError(DriveError):
    """The motor or the settings do not allow commissioning; the message says why."""


def reachable_current_A(R_s_ohm, u_max_V, injection_amplitude_V=0.0, dead_time_V=0.0):
    """The largest DC current [A] a current loop holds with the voltage vector limited to ``u_max_V``
    (U_dc/√3): BUS_HEADROOM·u_max less the HF amplitude and the dead-time voltage in αβ, through R_s."""
    room = BUS_HEADROOM * u_max_V - injection_amplitude_V - DEAD_TIME_AB * max(dead_time_V, 0.0)
    return math.inf if R_s_ohm <= 0.0 else max(room, 0.0) / R_s_ohm


def check_settings(settings, T_s):
    s = {**DEFAULTS, **(settings or {})}
    unknown = set(s) - set(DEFAULTS)
    if unknown:
        raise KeyError(f"commissioning: unknown setting(s) {', '.join(sorted(map(str, unknown)))} "
                       f"(known: {', '.join(sorted(DEFAULTS))})")
    try:
        number("injection_frequency_Hz", s["injection_frequency_Hz"], 0.0, 0.25 / T_s)
        number("hf_current_fraction", s["hf_current_fraction"], 0.0, 0.3)
        number("current_bandwidth_Hz", s["current_bandwidth_Hz"], 0.0, 0.05 / T_s)
        number("limit_margin", s["limit_margin"], 0.5, 1.0)
        number("d_sweep_fraction", s["d_sweep_fraction"], 0.0, 0.3)
        number("q_points", s["q_points"], 3, 65, low_inclusive=True, integer=True)
        number("polarity_margin", s["polarity_margin"], 0.0, 0.2)
        if s["q_points"] % 2 == 0:
            raise ValueError(f"q_points: must be odd (the grid holds zero), not {s['q_points']}")
    except ValueError as error:
        raise ValueError(f"commissioning: {error}") from None
    return s


class CommissioningProcedure:
    """The procedure for a motor known by its ``nameplate`` (drive_common.motor.nameplate.Nameplate) on an
    inverter ``rating`` (InverterRating), sampled every T_s [s]. Its current loop (current_bandwidth_Hz, ω) is a
    PI with both closed-loop poles at −ω (gain 2ωL − R on the measurement, integral ω²L, the nameplate's mean L
    and R_s): a voltage the loop does not know (the dead-time voltage, many times R_s·I on a high-voltage bus)
    is rejected in a few 1/ω whatever L/R, so each DC point is steady when measured; on the reference it acts
    with ωL only, so the reference still reaches the current as ω/(s + ω), without overshoot.
    ``step(k, m_a, m_b, m_c)`` takes the measured phase currents of sample k [A] and returns the command
    (u_α, u_β) [V] for the period after it; ``total_samples`` is the procedure's length; ``result()`` the
    identified record."""

    def __init__(self, nameplate, rating, T_s, settings=None):
        s = check_settings(settings, T_s)
        self.plate, self.T_s, self.settings = nameplate, T_s, s
        self.N = int(round(1.0 / (s["injection_frequency_Hz"] * T_s)))
        L_mean = 0.5 * (nameplate.L_d_H + nameplate.L_q_H)
        omega_h = 2.0 * math.pi / (self.N * T_s)
        nominal_V = s["hf_current_fraction"] * nameplate.rated_current_A * omega_h * L_mean
        w = 2.0 * math.pi * s["current_bandwidth_Hz"]
        self.kp = max(2.0 * w * L_mean - nameplate.R_s_ohm, w * L_mean)
        self.kp_reference, self.ki = w * L_mean, w * w * L_mean * T_s
        self.u_max = rating.U_dc_V / SQRT3
        self.delay = rating.delay_periods
        self.limit_A = nameplate.current_limit_A
        self.U_dc_V = rating.U_dc_V
        self.scaled = []
        self.R = nameplate.R_s_ohm
        room_V = BUS_HEADROOM * self.u_max - nameplate.R_s_ohm * nameplate.rated_current_A
        self.hf_volts_per_ampere = omega_h * L_mean
        self.hf_room_V = room_V
        self.injection_amplitude_V = max(min(nominal_V, room_V), MIN_HF_SHARE * nominal_V)
        if self.injection_amplitude_V < nominal_V:
            self.scaled.append(f"HF carrier {self.injection_amplitude_V:.3g} V, not {nominal_V:.3g} V: the "
                               f"{rating.U_dc_V:g} V bus leaves no more beside rated current through R_s")
        self._check_bus("DC", max(s["dc_levels"]) * nameplate.rated_current_A,
                        reachable_current_A(nameplate.R_s_ohm, self.u_max), "the nameplate's", "before any current")
        self.total_samples = sum(sum(SAMPLES[kind]) * count for kind, count in self._segment_counts())
        n = self.total_samples
        self.raw = np.zeros((n, 3))
        self.issued = np.zeros((n, 2))
        self.k = 0
        self.offsets = np.zeros(3)
        self.noise = 0.0
        self.gains = np.ones(3)
        self.V_dt = 0.0
        self.integral = np.zeros(2)
        self.reference = np.zeros(2)
        self.plan = self._plan()
        self.segment = next(self.plan)
        self.segment_start = 0
        self.done = False
        self.record = None

    def _check_bus(self, test, wanted_A, reachable_A, which, when):
        """CommissioningError before the ``test`` current ``wanted_A`` is applied where the bus cannot drive
        it (``reachable_A`` through ``which`` R_s); ``when``: the refusal's moment, in words."""
        if wanted_A > reachable_A:
            needed = f"a bus of about {self.U_dc_V * wanted_A / reachable_A:.3g} V drives it" if reachable_A > 0.0 \
                else "the HF carrier alone takes the whole voltage"
            raise CommissioningError(
                f"commissioning refused {when}: the {self.U_dc_V:g} V bus cannot drive the {test} test current: "
                f"{wanted_A:.3g} A wanted, at most {reachable_A:.3g} A reachable (through {which} R_s {self.R:.3g} Ω "
                f"within U_dc/√3 = {self.u_max:.3g} V); {needed}; nothing written")

    def _check_reached(self, window, i_ref_ab, test):
        """CommissioningError where a segment's mean current fell short of its reference ``i_ref_ab`` with the
        voltage at the modulation limit: the bus could not drive it."""
        wanted = math.hypot(*i_ref_ab)
        reached = float(np.hypot(*_alpha_beta(self.corrected(window["raw"])).mean(axis=0)))
        issued = float(np.mean(np.hypot(*window["issued"].T)))
        if wanted <= 0.0 or reached >= REACHED_SHARE * wanted or issued < BUS_HEADROOM * self.u_max:
            return
        raise CommissioningError(
            f"commissioning refused: the {self.U_dc_V:g} V bus did not drive the {test} test current: {wanted:.3g} A "
            f"wanted, {reached:.3g} A reached (the voltage at the modulation limit U_dc/√3 = {self.u_max:.3g} V: the "
            f"winding takes {issued / max(reached, 1e-9):.3g} Ω there against the nameplate's R_s "
            f"{self.plate.R_s_ohm:.3g} Ω); nothing written")

    def _segment_counts(self):
        s = self.settings
        return (("offsets", 1), ("dc", 6 * len(s["dc_levels"])), ("hf_zero", 1), ("polarity", 4),
                ("table", 3 * s["q_points"]), ("end", 1))

    def _segment(self, kind, i_ref_ab=None, hf=False):
        return Segment(kind, i_ref_ab, hf, *SAMPLES[kind])

    def _plan(self):
        """The segments, each decided from what the ones before measured (a generator: it receives each
        segment's samples and yields the next)."""
        s, plate = self.settings, self.plate
        window = yield self._segment("offsets")
        self.offsets = window["raw"].mean(axis=0)
        self.noise = float(np.sqrt(np.mean(window["raw"].var(axis=0))))
        dc = []
        for level in s["dc_levels"]:
            for j in range(6):
                angle = j * math.pi / 3.0
                current = level * plate.rated_current_A
                reference = (current * math.cos(angle), current * math.sin(angle))
                window = yield self._segment("dc", reference)
                self._check_reached(window, reference, "DC")
                dc.append((window["raw"].mean(axis=0) - self.offsets, window["issued"].mean(axis=0)))
        readings = np.array([r for r, _ in dc])
        self.gains = relative_gains(readings)
        phase = readings / self.gains
        self.R, self.V_dt = resistance_and_dead_time(_alpha_beta(phase), np.array([u for _, u in dc]), phase)
        self._clear_of_dead_time()
        window = yield self._segment("hf_zero", (0.0, 0.0), hf=True)
        gamma0 = self._admittance(window)
        low_axis, _, _ = saliency_axis(gamma0)
        current = _alpha_beta(window["phase"])
        ripple = float(np.max(np.hypot(*(current - current.mean(axis=0)).T)))
        reachable = reachable_current_A(self.R, self.u_max, self.injection_amplitude_V, self.V_dt)
        i_p = plate.rated_current_A
        if reachable < i_p:
            if reachable < MIN_POLARITY_SHARE * i_p:
                self._check_bus("polarity", i_p, reachable, "the measured", "after the DC points")
            self.scaled.append(f"polarity test at {reachable:.3g} A, not the rated {i_p:.3g} A: the {self.U_dc_V:g} V "
                               f"bus drives no more with the HF carrier through R_s {self.R:.3g} Ω")
            i_p = reachable
        asymmetries = []
        for axis in (low_axis, low_axis + 0.5 * math.pi):
            inductance = []
            for sign in (1.0, -1.0):
                reference = (sign * i_p * math.cos(axis), sign * i_p * math.sin(axis))
                window = yield self._segment("polarity", reference, hf=True)
                self._check_reached(window, reference, "polarity")
                inductance.append(1.0 / in_frame(self._admittance(window), axis)[0])
            asymmetries.append((inductance[1] - inductance[0]) / (0.5 * (inductance[0] + inductance[1])))
        j = int(np.argmax(np.abs(asymmetries)))
        self.asymmetry = float(asymmetries[j])
        if abs(self.asymmetry) > s["polarity_margin"]:
            d_axis = low_axis + 0.5 * math.pi * j + (math.pi if self.asymmetry < 0.0 else 0.0)
            self.polarity = "magnet found (the axis whose inductance saturates with current)"
        else:
            d_axis = low_axis
            self.polarity = ("not determined (no saturation asymmetry; d taken on the smaller inductance, "
                             "tables measured in either direction)")
        g_dd, g_qq, _ = in_frame(gamma0, d_axis)
        self.L_dh, self.L_qh = 1.0 / g_dd, 1.0 / g_qq
        self.saliency_ratio = (g_dd - g_qq) / (g_dd + g_qq)
        saliency_sign = 1.0 if g_dd >= g_qq else -1.0
        top = s["limit_margin"] * self.limit_A - ripple
        if reachable < top:
            self.scaled.append(f"tables up to {reachable:.3g} A, not {top:.3g} A (the current limit's): the "
                               f"{self.U_dc_V:g} V bus drives no more with the HF carrier through R_s {self.R:.3g} Ω")
            top = reachable
        sweep = s["d_sweep_fraction"] * plate.rated_current_A
        i_q_top = math.sqrt(max(top * top - sweep * sweep, 0.0))
        grid = np.linspace(-i_q_top, i_q_top, s["q_points"])
        shifts = np.zeros((len(grid), 3))
        ratios = np.zeros(len(grid))
        c, sn = math.cos(d_axis), math.sin(d_axis)
        for j, i_q in enumerate(grid):
            for m, i_d in enumerate((-sweep, 0.0, sweep)):
                reference = (c * i_d - sn * i_q, sn * i_d + c * i_q)
                window = yield self._segment("table", reference, hf=True)
                self._check_reached(window, reference, "saliency table")
                gamma = self._admittance(window)
                shifts[j, m] = axis_shift(gamma, d_axis, saliency_sign)
                if i_d == 0.0:
                    ratios[j] = saliency_ratio_of(gamma)
        points_d = np.tile([-sweep, 0.0, sweep], len(grid))
        points_q = np.repeat(grid, 3)
        shift_of, slope_of, self.surface_residual = saliency_surface(points_d, points_q, shifts.ravel())
        table = np.linspace(-i_q_top, i_q_top, TABLE_POINTS)
        shift, slope = shift_of(table), slope_of(table)
        self.saliency = "measured"
        if abs(self.saliency_ratio) < MIN_SALIENCY_RATIO:
            shift, slope = np.zeros(TABLE_POINTS), np.ones(TABLE_POINTS)
            self.saliency = (f"none measurable (|Δ|/Σ = {abs(self.saliency_ratio):.4f} < {MIN_SALIENCY_RATIO:g}): "
                             f"HF injection cannot tell this rotor's angle; tables left flat")
        self.peak_planned_A = top + ripple
        self.ripple_A = ripple
        self.record = Commissioning(self.R, self.V_dt, *self.gains, *self.offsets, self.noise, self.L_dh, self.L_qh,
                                    table, shift, slope, source="", saliency_ratio=np.interp(table, grid, ratios),
                                    saturation_asymmetry=abs(self.asymmetry))
        yield self._segment("end")
        yield None

    def _clear_of_dead_time(self):
        """Raise the HF amplitude to HF_PER_DEAD_TIME × the measured dead-time voltage in αβ (at most a ripple of
        MAX_HF_CURRENT_FRACTION of rated current, within the bus's room): at zero current the carrier's
        currents cross zero every half period, and what the dead-time model misses there near the crossings (the
        drive sees each sign at a sample, smoothed; the switches commute as they do) enters Γ as a share of
        the carrier's voltage (a drawn 28 pole-pair motor, 2.4 V of dead time under an 8 V carrier: L_qh +29 %;
        16 V: +0.2 %)."""
        wanted_V = HF_PER_DEAD_TIME * DEAD_TIME_AB * max(self.V_dt, 0.0)
        if wanted_V <= self.injection_amplitude_V:
            return
        top_V = min(MAX_HF_CURRENT_FRACTION * self.plate.rated_current_A * self.hf_volts_per_ampere,
                    self.hf_room_V)
        raised_V = min(wanted_V, top_V)
        if raised_V > self.injection_amplitude_V:
            self.scaled.append(f"HF carrier {raised_V:.3g} V, not {self.injection_amplitude_V:.3g} V: clear of the "
                               f"measured dead-time voltage {self.V_dt:.3g} V")
            self.injection_amplitude_V = raised_V

    def _admittance(self, window):
        """Γ over a measured window: each current step paired with the voltage applied between its
        samples: the command issued delay + 1 samples before the later one, less the measured dead-time
        voltage at the phase currents of the period's start."""
        phase = window["phase"][:-1]
        k_a, k_b = dead_time_direction.py_func(*phase.T, SMOOTHING_PER_RATED_CURRENT * self.plate.rated_current_A)
        applied = window["applied"] - self.V_dt * np.column_stack([k_a, k_b])
        return admittance(_alpha_beta(window["phase"]), applied, self.R, self.T_s)

    def corrected(self, raw):
        """Phase currents (… × 3) corrected by what is known so far (offsets, gains)."""
        return (np.asarray(raw) - self.offsets) / self.gains

    def step(self, k, m_a, m_b, m_c):
        """Sample k's measured currents [A] → the command (u_α, u_β) [V] for the period after it."""
        if self.done or k != self.k:
            raise ValueError(f"commissioning: sample {k} out of order (expected {self.k})")
        self.raw[k] = (m_a, m_b, m_c)
        seg = self.segment
        n_in = k - self.segment_start
        if seg.i_ref_ab is None:
            u = np.zeros(2)
            self.integral[:] = 0.0
        else:
            if n_in == 0:
                self.ramp_from = self.reference.copy()
            ramp = min(1.0, (n_in + 1) / RAMP_SAMPLES)
            self.reference = self.ramp_from + ramp * (np.asarray(seg.i_ref_ab) - self.ramp_from)
            error = self.reference - _alpha_beta(self.corrected(self.raw[max(0, k - self.N + 1):k + 1].mean(axis=0)))
            self.integral += self.ki * error
            u = self.kp * error - (self.kp - self.kp_reference) * self.reference + self.integral
            if seg.hf:
                phase = 2.0 * math.pi * (k % self.N) / self.N
                u = u + self.injection_amplitude_V * np.array([math.cos(phase), math.sin(phase)])
        magnitude = math.hypot(*u)
        if magnitude > self.u_max:
            u = u * (self.u_max / magnitude)
        self.issued[k] = u
        self.k = k + 1
        if self.k - self.segment_start == seg.settle + seg.measure:
            self._next_segment()
        return float(u[0]), float(u[1])

    def _next_segment(self):
        seg, start = self.segment, self.segment_start
        first, end = start + seg.settle, self.k
        raw = self.raw[first:end]
        phase = self.corrected(self.raw[first - 1:end]) if first > 0 else None
        lag = self.delay + 1
        applied = self.issued[first - lag:end - lag] if first >= lag else None
        window = {"raw": raw, "issued": self.issued[first:end], "phase": phase, "applied": applied}
        self.segment_start = self.k
        self.segment = self.plan.send(window)
        if self.segment is None:
            self.done = True

    def result(self):
        """The identified Commissioning record (source empty until saved or loaded)."""
        if not self.done:
            raise ValueError("commissioning: the procedure has not finished")
        return self.record

    def conditions(self):
        """What the record was measured under: test currents, HF carrier, polarity test, duration."""
        return {"shaft": "held (brake)",
                "duration_s": self.total_samples * self.T_s, "T_s_s": self.T_s,
                "injection_frequency_Hz": 1.0 / (self.N * self.T_s),
                "injection_amplitude_V": self.injection_amplitude_V,
                "hf_ripple_A": self.ripple_A, "dc_levels_A": [lv * self.plate.rated_current_A
                                                               for lv in self.settings["dc_levels"]],
                "current_limit_A": self.limit_A, "peak_planned_A": self.peak_planned_A,
                "polarity": self.polarity, "polarity_L_dh_asymmetry": self.asymmetry,
                "saliency_ratio": float(self.saliency_ratio), "saliency": self.saliency,
                "saliency_fit_residual_rad": float(self.surface_residual), "scaled": list(self.scaled)}


def procedure_for_scenario(scenario, settings=None):
    """The procedure for the scenario's motor, told its nameplate and its inverter's rating only."""
    return CommissioningProcedure(scenario.motor.nameplate, scenario.motor.inverter, scenario.T_s,
                                  settings)


def _alpha_beta(phase):
    """Phase quantities (… × 3) → (… × 2) by the amplitude-invariant Clarke transform (drive_common.math.frames)."""
    phase = np.asarray(phase, dtype=float)
    return np.stack(clarke.py_func(phase[..., 0], phase[..., 1], phase[..., 2]), axis=-1)
