"""A recording as replay and compare score it: the bag's log, and what the drive that recorded it knew
(its motor, sample period, command delay, commissioning, estimator, injection) with where each came
from: the scenario the bag names, its contract-v2 drive_config, the command line, or a stated default.
Any contract bag works: the project's own, one from another recorder with a v2 drive_config, or one
without drive_config given the motor and the sample period (docs/recordings.md)."""
import dataclasses
import math

import numpy as np

from drive_common.contract.estimator_states import TRACKING
from drive_common.contract.log import COLUMN
from drive_common.contract.settings import shown
from drive_common.contract.topics import BLOCK_TOPIC, SAMPLE_LOGGED, TOPICS
from drive_common.motor.commissioning import (
    NAMEPLATE_ONLY,
    CommissioningError,
    nameplate_commissioning,
    recorded_commissioning,
    resolve_commissioning,
)
from drive_common.motor.motor_file import load_nameplate, recorded_nameplate
from drive_common.motor.nameplate import NameplateError
from drive_tools.bags.common import BagError
from drive_tools.bags.reader import bag_scenario, bag_topics, has_ground_truth, log_from_topics, recorded_estimator

from .excitation import AXIS_BLOCK_S, describe_excitation, signed_carrier
from .metrics import _mask
from .metrics import windows as scenario_windows

CONTRACT_DELAY_PERIODS = 1
"""The contract's usual computation delay: a bag that does not say otherwise was recorded with it."""
AUTO_WINDOW_S = 0.1
"""Automatic windows are built of blocks this long..."""
AUTO_START_S = 0.2
"""...after this start (the replayed estimators' own start-up)..."""
AUTO_SPEED_SPAN = 0.02
"""...in which the recorded estimate's speed (mechanical, smoothed over AUTO_SMOOTHING_S) spans at most
this share of the rated speed plus AUTO_SPEED_SHARE of its own magnitude, and the recorded estimator
tracks throughout."""
AUTO_SPEED_SHARE = 0.05
AUTO_SMOOTHING_S = 0.02
AUTO_KNOWN_SHARE = 0.99
"""...with the speed known in this share of a block's samples (lost messages hold the last one)."""


STATED_SETTINGS = "drive_config estimator_settings"
"""The source of estimator settings a drive stated in its recording's drive_config."""


@dataclasses.dataclass
class Recording:
    """A bag read for scoring; ``sources`` says where each piece came from."""

    path: str
    log: np.ndarray
    T_s: float
    nameplate: object
    commissioning: object
    delay_periods: int
    U_dc_V: float
    """The recording drive's DC-link voltage [V] (∞ where the bag does not say): an estimator's own test
    pulses are sized within it, so replay builds it on the same bus."""
    estimator: str
    """The recording drive's estimator ("" when the bag does not say)."""
    estimator_settings: dict
    controller_settings: dict
    """The recording controller's settings (its scenario's ``controller:`` or drive_config ``controller``; {}:
    its defaults): the current path it ran, whose saliency shift the drive's estimator followed."""
    injection: dict
    """{frequency_Hz, amplitude_V} the recording injected, handed to the replayed estimators."""
    excitation: dict
    """The recorded injection as measured (excitation.describe_excitation)."""
    carrier: np.ndarray
    """The recorded injection as a signed carrier along its own axis per sample [V] (excitation.signed_carrier)."""
    windows: list
    start_s: float
    scenario: object
    """The scenario the bag was recorded from (drive_common.config Scenario), or None."""
    sources: dict
    timing: dict
    """The stamps' epoch, jitter and messages off the grid (drive_tools.bags.reader.log_from_topics)."""
    gaps: dict
    """``missing_samples`` per topic within the replayed span, and ``cut_samples`` left off its end."""
    zero_volts: np.ndarray
    """Per sample: the period from it ran at zero volts, whatever was commanded (the bag's `zero_voltage`)."""
    settings_stated: bool = False
    """``estimator_settings`` are the drive's own, whole (drive_config): its injection is in them, so replay
    builds the recording's estimator on them alone (one that picks its carrier itself keeps its own)."""

    @property
    def n_p(self):
        return self.nameplate.n_p

    @property
    def ground_truth(self):
        return has_ground_truth(self.log)

    def report(self):
        """What a replay or compare report says of the recording."""
        return {"bag": self.path, "scenario": self.scenario.name if self.scenario else None,
                "recorded_estimator": self.estimator or None, "samples": int(self.log.shape[0]),
                "sample_period_s": self.T_s, "motor": self.nameplate.name, "ground_truth": self.ground_truth,
                "excitation": self.excitation, "sources": self.sources, "timing": self.timing,
                "missing_samples": self.gaps["missing_samples"], "cut_samples": self.gaps["cut_samples"],
                "windows": {"source": self.sources["windows"], "steady_s": [list(w) for w in self.windows]},
                "motor_figures": self.motor_figures()}

    def motor_figures(self):
        """The class figures a corpus report groups the bag by: pole pairs, the HF saliency L_qh/L_dh the
        replay's commissioning holds (the nameplate's L_q/L_d where it is the nameplate alone), and the speed
        in the scored windows: the median |ω_m| (ground truth, else the recorded estimate) per rated speed
        (None where the nameplate gives none)."""
        plate, c = self.nameplate, self.commissioning
        column = "omega_m" if self.ground_truth else "omega_e_hat"
        speed = self.log[_mask(self.log[:, COLUMN["t"]], self.windows), COLUMN[column]]
        speed = np.abs(speed[np.isfinite(speed)]) / (1.0 if self.ground_truth else self.n_p)
        rated = plate.rated_speed_rpm * np.pi / 30.0
        share = float(np.median(speed) / rated) if speed.size and np.isfinite(rated) and rated > 0 else None
        return {"n_p": int(plate.n_p), "saliency": float(c.L_qh_H / c.L_dh_H), "speed_per_rated": share}


def read_recording(path, motor=None, sample_period_s=None, commissioning=None, windows=None, namespace=None):
    """A Recording of the bag at ``path``. The command line's pieces: ``motor`` (a shipped motor or a
    motor file, --motor) and ``sample_period_s`` (--sample-period) supply what the bag does not say (a
    bag's own is used where it has one, so one command serves a corpus); ``commissioning`` (a file or
    'nameplate', --commissioning) and ``windows`` ((t0, t1) [s], --windows) replace the bag's; ``namespace``
    (--namespace) picks one drive of a bag holding several. BagError names the bag and the option that supplies a
    missing piece."""
    path = str(path)
    namespace, topics, configs = bag_topics(path, namespace)
    sources = {}
    T_s = _sample_period(path, sample_period_s, configs, sources)
    scenario, unloadable = _scenario(path, configs)
    v2 = next((c for c in configs if isinstance(c.get("motor"), dict)), None)
    plate = _nameplate(path, motor, scenario, v2, sources)
    recorded_n_p = next((c["n_p"] for c in configs if "n_p" in c), None)
    if recorded_n_p is not None and recorded_n_p != plate.n_p:
        raise BagError(f"{path}: drive_config says n_p {recorded_n_p}, the motor ({sources['motor']}) {plate.n_p}")
    log, T_s, timing, zero_volts = log_from_topics(path, namespace, topics, configs, T_s, plate.n_p,
                                                   sources["sample_period"])
    log, gaps = whole_span(path, log, topics)
    zero_volts = zero_volts[:log.shape[0]]
    delay = _delay(scenario, configs, sources)
    U_dc_V = _bus_voltage(path, scenario, configs, sources)
    known = _commissioning(path, plate, commissioning, configs, sources)
    recorded = recorded_estimator(configs)
    sources["recorded_estimator"] = "drive_config" if recorded else "not in the bag"
    settings = _estimator_settings(path, scenario, configs, recorded, sources)
    carrier, excitation = _excitation(log, T_s, sources)
    injection = _injection(scenario, configs, excitation, sources)
    if scenario is not None:
        scenario = dataclasses.replace(scenario, duration_s=log.shape[0] * T_s, T_s=T_s)
        sources["scenario"] = scenario.name
    else:
        sources["scenario"] = unloadable or "none named in the bag"
    duration = log.shape[0] * T_s
    if windows:
        for t0, t1 in windows:
            if t1 > duration + 1e-12:
                raise BagError(f"--windows: {t0:g}:{t1:g} s ends after the recording {path} ({duration:g} s)")
        chosen, start, sources["windows"] = list(windows), min(w[0] for w in windows), "--windows"
    elif scenario is not None:
        chosen, start = scenario_windows(scenario)[0], scenario.metrics_start_s
        sources["windows"] = f"scenario {scenario.name}"
    else:
        chosen, note = automatic_windows(log, T_s, plate)
        if not chosen:
            named = next((c["scenario"] for c in configs if isinstance(c.get("scenario"), str)), None)
            why = (f"; drive_config names scenario '{named}' but no source to take its windows from" if named
                   else "")
            raise BagError(f"{path}: no steady interval found to score ({note}){why}; give --windows T0:T1[,...]")
        start, sources["windows"] = chosen[0][0], f"automatic: {note}"
    controller = _controller(path, scenario, configs, sources)
    return Recording(path, log, T_s, plate, known, delay, U_dc_V, recorded, settings, controller, injection,
                     excitation, carrier, chosen, start, scenario, sources, timing, gaps, zero_volts,
                     settings_stated=sources["estimator_settings"] == STATED_SETTINGS)


def whole_span(path, log, topics):
    """(log up to its last whole sample, gaps): a recording cut mid-sample (a signal, a power loss) ends
    where currents and voltage_command (what every replayed estimator reads) last arrived; within it, each
    logged topic's missing samples are counted (lost messages are gaps, replay steps over them:
    drive_tools.evaluation.replay). BagError where no sample is whole."""
    whole = np.isfinite(log[:, COLUMN["i_a_meas"]]) & np.isfinite(log[:, COLUMN["u_alpha"]])
    if not whole.any():
        raise BagError(f"{path}: no sample holds both currents and voltage_command; nothing to replay")
    end = int(np.nonzero(whole)[0][-1]) + 1
    cut, log = log.shape[0] - end, log[:end]
    missing = {}
    for topic in SAMPLE_LOGGED:
        column = COLUMN[TOPICS[topic].log_columns[0]]
        if topics.get(topic) or topics.get(BLOCK_TOPIC[topic]):
            missing[topic] = int(np.isnan(log[:, column]).sum())
    return log, {"missing_samples": missing, "cut_samples": cut}


def _sample_period(path, given, configs, sources):
    if given is not None and not (math.isfinite(given) and 0.0 < given < 1.0):
        raise BagError(f"--sample-period: {given:g} is not a sample period in seconds (0 < S < 1)")
    recorded = next((c["T_s_s"] for c in configs if "T_s_s" in c), None)
    if recorded is not None:
        if isinstance(recorded, bool) or not isinstance(recorded, (int, float)) or not 0.0 < recorded < 1.0:
            raise BagError(f"{path}: drive_config T_s_s {shown(recorded)} is not a sample period in seconds")
        sources["sample_period"] = "drive_config T_s_s" + (" (--sample-period not used)" if given else "")
        return float(recorded)
    if not given:
        raise BagError(f"{path}: no drive_config gives the sample period; give --sample-period S")
    sources["sample_period"] = "--sample-period"
    return float(given)


def _scenario(path, configs):
    """(the bag's scenario or None, why a named one was not loaded or None)."""
    try:
        return bag_scenario(path, configs), None
    except BagError as error:
        return None, str(error).removeprefix(f"{path}: ")


def _nameplate(path, motor, scenario, v2, sources):
    unused = " (--motor not used)" if motor else ""
    try:
        if scenario is not None:
            sources["motor"] = f"scenario {scenario.name}{unused}"
            return scenario.motor.nameplate
        if v2 is not None:
            sources["motor"] = f"drive_config motor{unused}"
            return recorded_nameplate(v2["motor"], f"{path}: drive_config motor")
        if motor:
            sources["motor"] = "--motor"
            return load_nameplate(motor, "--motor")
    except NameplateError as error:
        raise BagError(str(error)) from None
    raise BagError(f"{path}: no drive_config names the motor; give --motor PRESET|FILE")


def _delay(scenario, configs, sources):
    if scenario is not None:
        sources["command_delay"] = f"scenario {scenario.name}"
        return scenario.drive_delay_periods()
    given = next((c["command_delay_periods"] for c in configs if "command_delay_periods" in c), None)
    if isinstance(given, int) and not isinstance(given, bool) and given >= 0:
        sources["command_delay"] = "drive_config command_delay_periods"
        return given
    sources["command_delay"] = f"the contract's usual {CONTRACT_DELAY_PERIODS} period (not in the bag)"
    return CONTRACT_DELAY_PERIODS


def _estimator_settings(path, scenario, configs, recorded, sources):
    """The settings the recording drive built its estimator ``recorded`` with: drive_config's
    ``estimator_settings`` (the drive's checked settings, loops scaled to the motor), else its scenario's
    (a bag recorded before drives stated them), else {} (its defaults)."""
    given = next((c for c in configs if c.get("estimator_settings") is not None), None)
    if given is not None and given.get("estimator", recorded) == recorded:
        if not isinstance(given["estimator_settings"], dict):
            raise BagError(f"{path}: drive_config estimator_settings {shown(given['estimator_settings'])} is not "
                           f"a mapping of estimator settings")
        sources["estimator_settings"] = STATED_SETTINGS
        return dict(given["estimator_settings"])
    if scenario is not None and recorded == scenario.estimator:
        sources["estimator_settings"] = f"scenario {scenario.name}"
        return dict(scenario.estimator_settings)
    sources["estimator_settings"] = "not in the bag: the estimator's defaults"
    return {}


def _controller(path, scenario, configs, sources):
    """The recording controller's settings: its scenario's, else drive_config ``controller``, else {} (its
    defaults)."""
    if scenario is not None:
        sources["controller"] = f"scenario {scenario.name}"
        return dict(scenario.controller)
    given = next((c["controller"] for c in configs if "controller" in c and "parameters" not in c), None)
    if given is None:
        sources["controller"] = "not in the bag: the controller's defaults"
        return {}
    if not isinstance(given, dict):
        raise BagError(f"{path}: drive_config controller {shown(given)} is not a mapping of controller settings")
    sources["controller"] = "drive_config controller"
    return dict(given)


def _bus_voltage(path, scenario, configs, sources):
    """The recording drive's DC-link voltage [V]: its scenario's inverter, else drive_config ``inverter``
    (``U_dc_V``), else ∞ (a bag recorded before drives stated it)."""
    if scenario is not None:
        sources["bus_voltage"] = f"scenario {scenario.name}"
        return scenario.motor.inverter.U_dc_V
    given = next((c["inverter"] for c in configs if isinstance(c.get("inverter"), dict)), None)
    if given is None:
        sources["bus_voltage"] = "not in the bag: test pulses sized as on an unlimited bus"
        return math.inf
    U_dc_V = given.get("U_dc_V")
    if U_dc_V is None:
        sources["bus_voltage"] = "drive_config inverter (not stated)"
        return math.inf
    if isinstance(U_dc_V, bool) or not isinstance(U_dc_V, (int, float)) or not 0.0 < U_dc_V < math.inf:
        raise BagError(f"{path}: drive_config inverter.U_dc_V {shown(U_dc_V)} is not a bus voltage in volts")
    sources["bus_voltage"] = "drive_config inverter.U_dc_V"
    return float(U_dc_V)


def _commissioning(path, plate, given, configs, sources):
    """The commissioning the replay runs on: the command line's, else the one the recording drive ran on
    (its drive_config ``commissioning``), else the nameplate alone, never a file looked up where the replay
    happens to run; ``sources`` says which."""
    recorded = next((c["commissioning"] for c in configs if "commissioning" in c), None)
    try:
        if given:
            known = resolve_commissioning(plate, given, "--commissioning")
            sources["commissioning"] = f"--commissioning {given}" + (" (the bag's not used)" if recorded else "")
        elif recorded is not None:
            known = recorded_commissioning(plate, recorded, "drive_config commissioning")
            sources["commissioning"] = known.source if known.source != NAMEPLATE_ONLY else (
                "drive_config commissioning: the recording drive knew its nameplate only")
        else:
            known = nameplate_commissioning(plate)
            sources["commissioning"] = ("nameplate only: the bag records no commissioning (give --commissioning "
                                        "FILE)")
    except CommissioningError as error:
        raise BagError(f"{path}: {error}") from None
    return known


def _excitation(log, T_s, sources):
    """(signed carrier, excitation.describe_excitation) of the recorded excitation: the `injection` topic, or
    where the bag has none voltage_command less its average over AXIS_BLOCK_S (the fundamental)."""
    injected = log[:, [COLUMN["u_inj_alpha"], COLUMN["u_inj_beta"]]]
    if np.isfinite(injected).all():
        sources["excitation"] = "injection"
    else:
        voltage = np.nan_to_num(log[:, [COLUMN["u_alpha"], COLUMN["u_beta"]]])
        width = max(1, int(round(AXIS_BLOCK_S / T_s)))
        kernel = np.ones(width) / width
        average = np.column_stack([np.convolve(voltage[:, j], kernel, mode="same") for j in range(2)])
        injected = voltage - average
        sources["excitation"] = f"voltage_command less its {AXIS_BLOCK_S * 1e3:g} ms average (no injection topic)"
    carrier, across = signed_carrier(injected, T_s)
    return carrier, describe_excitation(carrier, across, T_s)


def _injection(scenario, configs, excitation, sources):
    if scenario is not None:
        sources["injection"] = f"scenario {scenario.name}"
        return dict(scenario.injection)
    for config in configs:
        given = config.get("injection")
        if isinstance(given, dict) and all(isinstance(given.get(k), (int, float)) and given[k] > 0
                                           for k in ("frequency_Hz", "amplitude_V")):
            sources["injection"] = "drive_config injection"
            return {"frequency_Hz": float(given["frequency_Hz"]), "amplitude_V": float(given["amplitude_V"])}
    if excitation["kind"] == "none":
        sources["injection"] = "none recorded"
        return {}
    sources["injection"] = "measured from the recorded injection"
    return {"frequency_Hz": excitation["frequency_Hz"], "amplitude_V": excitation["amplitude_V"]}


def automatic_windows(log, T_s, plate):
    """([(t0, t1)], how they were found): from AUTO_START_S on, runs of AUTO_WINDOW_S blocks where the true
    speed (ground truth) is steady, once the recorded estimator first tracked (its start-up, whose polarity
    the replayed estimators take, is over); without ground truth, where the recorded speed estimate is steady
    and the recorded estimator tracks. With ground truth the windows do not depend on how the recording's own
    estimator did after its start (a corpus scored only where it worked would favour it)."""
    c = COLUMN
    truth = has_ground_truth(log)
    speed = log[:, c["omega_m"]] if truth else log[:, c["omega_e_hat"]] / plate.n_p
    which = "the true speed (ground truth)" if truth else "the recorded estimate's speed"
    if not np.isfinite(speed).any():
        return [], "the bag has neither rotor_estimate nor rotor_state"
    known = np.isfinite(speed)
    speed = held(speed)
    smooth = max(1, int(round(AUTO_SMOOTHING_S / T_s)))
    filled = np.nan_to_num(speed)
    smoothed = np.convolve(filled, np.ones(smooth) / smooth, mode="same")
    state = log[:, c["state"]]
    tracked = np.isnan(state) | (state == TRACKING)
    if truth:
        tracked = np.maximum.accumulate(tracked)
    rated = plate.rated_speed_rpm * math.pi / 30.0
    block = max(1, int(round(AUTO_WINDOW_S / T_s)))
    chosen = []
    for k0 in range(int(round(AUTO_START_S / T_s)), log.shape[0] - block + 1, block):
        part = slice(k0, k0 + block)
        values = smoothed[part]
        span = float(values.max() - values.min())
        steady = (span <= AUTO_SPEED_SPAN * rated + AUTO_SPEED_SHARE * float(np.abs(values).mean())
                  and known[part].mean() >= AUTO_KNOWN_SHARE and tracked[part].all())
        if steady:
            t0, t1 = k0 * T_s, (k0 + block) * T_s
            if chosen and abs(chosen[-1][1] - t0) < 0.5 * T_s:
                chosen[-1] = (chosen[-1][0], t1)
            else:
                chosen.append((t0, t1))
    return chosen, (f"{AUTO_WINDOW_S:g} s blocks from {AUTO_START_S:g} s where {which} spans at most "
                    f"{AUTO_SPEED_SPAN:.0%} of rated speed + {AUTO_SPEED_SHARE:.0%} of itself"
                    + (", after the recorded estimator first tracked" if truth else
                       " and the recorded estimator tracks"))


def held(values, lost=None):
    """``values`` with each sample the recording lost (NaN, or ``lost``) holding the last one before it: the
    recorded estimate handed to the replayed estimators' encoder inputs across a gap."""
    missing = np.isnan(values) if lost is None else lost
    index = np.where(missing, 0, np.arange(values.size))
    np.maximum.accumulate(index, out=index)
    return values[index]
