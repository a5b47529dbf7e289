"""What every estimator core provides, and the registry the runner and the nodes build them from.

A core is a numba step function called once per sample k, on named records
(drive_common.contract.estimator_records):

    step(x, p, k, sample, out)

``sample`` (SAMPLE) holds the measured phase currents (corrected by the commissioned calibration), the
voltage that acted in the period before sample k, the one that made the current step i[k] − i[k−1]:
`voltage_command`(k−1−d), d the drive's delay (drive_common.math.command_delay; the caller keeps the delay
line, so a block of samples needs only commands of earlier blocks), and the encoder's angle and speed,
read only by the ``sensored`` pass-through (and in replay by an estimator taking the recording's polarity).
The step writes ``out`` (ESTIMATE): θ̂_e, unwrapped, ω̂_e for the speed loop, the HF voltage u_inj to
superimpose for the period that follows sample k (stationary frame), the demodulated error ε, ``signal``
the measured angle-information strength (estimator-specific units, documented per estimator), ``state``
the start-up state code (startup.py: 0 hold, 1 aligning, 2 polarity test, 3 tracking, 4 lock lost; the
controller applies torque only once it has reached 3), the carrier amplitude it injects with [V] (0:
none), the weight of the back-EMF observer in θ̂ (0 … 1) and the source θ̂ follows
(drive_common.contract.estimator_states). x is the estimator's state, one record of its own dtype whose
``theta`` and ``omega`` are θ̂ and ω̂ (filters, rings and the start-up's ``startup`` among its fields); p
its parameters, the start-up's as ``p.startup``. Every estimator starts at θ̂ = 0, ω̂ = 0: it is told
nothing of the angle.

What an estimator knows of the motor is its nameplate (``drive_common.motor.nameplate``) and the commissioning
record measured on it (``drive_common.motor.commissioning``); never the plant.
"""
import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np
from numba import njit

from drive_common.contract.settings import Key, shown

from .block import EstimatorCore, sample_inputs


@dataclass(frozen=True)
class Estimator:
    """A built estimator: its step kernel, parameters and fresh state."""

    name: str
    step: Callable
    params: Any
    state: np.ndarray
    """Its state record, as a one-element structured array (``state[0]`` is the kernels' x)."""
    injection_frequency_Hz: float
    tracking_bandwidth_Hz: float = math.inf
    """Natural frequency of the angle-tracking loop (∞ for a sensor): the speed loop is kept below it."""
    tracking_current_limit_A: float = None
    """The largest current at which its angle information holds (injecting estimators; None: no limit)."""
    tracking_current_bound: tuple = None
    """(bound, why, current [A]) where its own predicted angle error, not the commissioned tables, sets
    tracking_current_limit_A (hf_estimator.build.predicted_current_limit); None otherwise."""
    tracking_acceleration_rad_s2: float = math.inf
    """The electrical acceleration its tracking follows within its lag budget where its injection leads over the
    whole speed range (drive_common.motor.scaled_loops.tracked_acceleration_e_rad_s2; ∞: no bound): the
    controller ramps the speed reference within it."""
    tracking_loop: tuple = None
    """(k_p [1/s], k_i [1/s²], k_a [1/s³], delay [s]) of its tracking loop on an error of unit slope, the delay that
    of its error path, where its speed estimate is that loop's integrator (foc_controller.speed_margin.TrackingLoop:
    the speed loop keeps its margins on it), and for an injecting estimator the smallest and largest slope of its
    error within tracking_current_limit_A (the commissioned convergence slope F); None: a type-2 loop at
    tracking_bandwidth_Hz is assumed."""
    injection_amplitude_V: float = None
    """The HF amplitude it injects when it chooses it itself (None: the scenario's)."""
    injection_note: str = ""
    """Why it raised the scenario's amplitude ("" when it did not)."""
    settings: dict = None
    """The checked settings the drive built it with (the loops scaled to the motor included; None: not
    built by the drive), stated in drive_config so that a replay of the recording builds it the same."""

    def core(self, state=None):
        """What the block kernels step with ``step`` (block.EstimatorCore): its parameters, this estimator's
        state (or ``state``, e.g. a copy) and a SAMPLE buffer of its own."""
        return EstimatorCore(self.params, self.state if state is None else state, sample_inputs())

    def facts(self):
        """What the controller needs to know of this estimator and how it injects (its drive_config)."""
        return {"estimator": self.name, "injection_frequency_Hz": self.injection_frequency_Hz,
                "injection_amplitude_V": self.injection_amplitude_V, "injection_note": self.injection_note,
                "tracking_bandwidth_Hz": self.tracking_bandwidth_Hz,
                "tracking_current_limit_A": self.tracking_current_limit_A,
                "tracking_current_bound": None if self.tracking_current_bound is None
                else list(self.tracking_current_bound),
                "tracking_acceleration_rad_s2": self.tracking_acceleration_rad_s2,
                "tracking_loop": None if self.tracking_loop is None else [float(v) for v in self.tracking_loop],
                "estimator_settings": self.settings}


class _Registered(NamedTuple):
    factory: Callable
    description: str
    injects: bool
    paper: str
    excitation: str
    injection_kind: str


_REGISTRY = {}


EXCITATION_NEEDS = {"carrier": "its own carrier: a pulsating injection at its frequency and carrier phase, which it "
                              "demodulates",
                   "any": "any injection whose voltage is known (it fits the admittance to the applied voltage)",
                   "encoder": "no injection; the ground truth (rotor_state) as its encoder",
                   "backemf": "no injection; the applied voltage and the currents (a back-EMF model: at speed only)"}
"""What an estimator needs of a recording's excitation to be measured by replaying it (docs/recordings.md)."""


def register(name, description, paper, injects=True, excitation="carrier", injection_kind="pulsating_sine"):
    """Register ``factory(nameplate, T_s, settings, commissioning, inverter) -> Estimator``
    from the module named ``name``; ``paper``: the section it implements; ``injects``: it takes the
    settings frequency_Hz and amplitude_V for its HF injection; ``excitation``: what it needs of a
    recording (EXCITATION_NEEDS); ``injection_kind``: its injection as drive_config names it (contract v2:
    pulsating_sine, alternating, square, rotating, none)."""
    def wrap(factory):
        _REGISTRY[name] = _Registered(factory, description, injects, paper, excitation, injection_kind)
        return factory
    return wrap


def contract_injection(facts, scenario_injection):
    """The drive_config ``injection`` object of contract v2 {kind, frequency_Hz, amplitude_V} of an
    estimator (its Estimator.facts()) injecting the scenario's ``scenario_injection`` unless it chose its
    own frequency or amplitude."""
    kind = _entry(facts["estimator"]).injection_kind
    if kind == "none":
        return {"kind": "none", "frequency_Hz": 0.0, "amplitude_V": 0.0}
    amplitude = facts["injection_amplitude_V"] or scenario_injection.get("amplitude_V")
    return {"kind": kind, "frequency_Hz": facts["injection_frequency_Hz"], "amplitude_V": amplitude}


PLUGIN_GROUP = "pmsm_drive.estimators"
"""The entry-point group of estimators in packages of their own (docs/estimator-plugins.md): an entry point
names the module whose import registers, with ``register``, the estimator of the entry point's name."""
_PLUGIN_ERRORS = {}
"""Installed plugins that could not be loaded: name → why."""
_installed_loaded = False


def _load_installed():
    """Import every installed plugin of PLUGIN_GROUP once; one that fails is kept in _PLUGIN_ERRORS."""
    global _installed_loaded
    if _installed_loaded:
        return
    _installed_loaded = True
    from importlib.metadata import entry_points
    for point in entry_points(group=PLUGIN_GROUP):
        if point.name in _REGISTRY:
            continue
        try:
            point.load()
        except Exception as error:  # a plugin's own failure, whatever it is, is its entry's, not the drive's
            _PLUGIN_ERRORS[point.name] = f"plugin {point.value}: {type(error).__name__}: {error}"
            continue
        if point.name not in _REGISTRY:
            _PLUGIN_ERRORS[point.name] = (f"plugin {point.value}: registers no estimator named '{point.name}' "
                                          f"(hf_estimator.interface.register)")


def _load_reference(name):
    """``module:factory`` (a dotted module on the path or a .py file, and its factory registered with
    ``register``, by its function's name or the name it registered): that estimator, also under this name.
    KeyError naming what failed."""
    import importlib
    import importlib.util
    import sys
    from pathlib import Path
    module_name, _, factory_name = name.rpartition(":")
    try:
        if module_name.endswith(".py"):
            path = Path(module_name).resolve()
            spec = importlib.util.spec_from_file_location(f"estimator_plugin_{path.stem}", path)
            if spec is None or not path.is_file():
                raise FileNotFoundError(f"no file {path}")
            module = importlib.util.module_from_spec(spec)
            sys.modules[spec.name] = module
            spec.loader.exec_module(module)
        else:
            module = importlib.import_module(module_name)
    except Exception as error:  # the plugin's import, whatever it raises, is refused in one line
        raise KeyError(f"estimator '{name}': {type(error).__name__}: {error}") from None
    factory = getattr(module, factory_name, None)
    found = [entry for entry in _REGISTRY.values() if entry.factory is factory and factory is not None]
    found += [entry for key, entry in _REGISTRY.items()
              if key == factory_name and getattr(entry.factory, "__module__", None) == module.__name__]
    if not found:
        registered = sorted(key for key, entry in _REGISTRY.items()
                            if ":" not in key and getattr(entry.factory, "__module__", None) == module.__name__)
        raise KeyError(f"estimator '{name}': {module_name} has no factory '{factory_name}' registered with "
                       f"hf_estimator.interface.register (it registers: {', '.join(registered) or 'none'})")
    _REGISTRY[name] = found[0]


def _entry(name):
    if name not in _REGISTRY:
        _load_installed()
    if name not in _REGISTRY and name in _PLUGIN_ERRORS:
        raise KeyError(f"estimator '{name}': {_PLUGIN_ERRORS[name]}")
    if name not in _REGISTRY and ":" in name:
        _load_reference(name)
    if name not in _REGISTRY:
        raise KeyError(f"unknown estimator '{name}' (known: {', '.join(estimator_names())})")
    return _REGISTRY[name]


def known_estimator(name):
    """Whether ``name`` is a registered estimator, an installed plugin's or a loadable ``module:factory``;
    KeyError naming why a plugin named so cannot be loaded."""
    try:
        _entry(name)
    except KeyError:
        if name in _PLUGIN_ERRORS or ":" in name:
            raise
        return False
    return True


def plugin_errors():
    """{name: why} of the installed plugins that could not be loaded."""
    _load_installed()
    return dict(_PLUGIN_ERRORS)


def injects(name):
    return _entry(name).injects


def excitation_need(name):
    """What the estimator ``name`` needs of a recording's excitation (a key of EXCITATION_NEEDS)."""
    return _entry(name).excitation


def estimator_names():
    """The registered estimators and the installed plugins' (not the ``module:factory`` references)."""
    _load_installed()
    return sorted(name for name in _REGISTRY if ":" not in name)


def describe(name):
    """{name, description, paper, module} of a registered estimator."""
    entry = _entry(name)
    return {"name": name, "description": entry.description, "paper": entry.paper,
            "module": entry.factory.__module__}


def make_estimator(name, nameplate, T_s, settings, commissioning, inverter):
    """Build the estimator ``name`` for a motor known by its ``nameplate`` (drive_common.motor.nameplate) and
    ``commissioning`` record (the HF inductances and saliency-shift tables measured at standstill) on
    ``inverter`` (drive_common.motor.nameplate.InverterRating: its U_dc, ∞ where unknown, and delay_periods the
    drive's whole delay from sample to applied command). KeyError or ValueError name the setting at fault."""
    return _entry(name).factory(nameplate, T_s, dict(settings or {}), commissioning, inverter)


MIN_INJECTION_FREQUENCY_HZ = 10.0
"""An HF carrier lies far above the fundamental; below this it is a mistake (and its period overflows)."""
MAX_CARRIER_SAMPLES = 1000
MAX_DELAY_PERIODS = 200
"""The rings in an estimator's state hold up to this many samples of one carrier period and of the drive's
delay (blocks of 100 samples answered 101 periods late: 200), whatever the motor and sampling: one state
layout per estimator, compiled once (docs/architecture.md "Estimator records")."""


@njit(cache=True)
def stator_resistance(R_commissioned_ohm, R_tracked_ohm):
    """The stator resistance [Ω] for a sample's resistive drop: the one the drive tracks as its winding
    warms (SAMPLE.R_s_ohm) when it gives one (> 0), else the commissioned one."""
    return R_tracked_ohm if R_tracked_ohm > 0.0 else R_commissioned_ohm


def ring_capacity(carrier_samples, delay_periods):
    """Check a carrier of ``carrier_samples`` per period and the drive's delay against the rings' capacity;
    ValueError naming what does not fit."""
    if carrier_samples > MAX_CARRIER_SAMPLES:
        raise ValueError(f"frequency_Hz: {carrier_samples} samples per carrier period, more than the "
                         f"{MAX_CARRIER_SAMPLES} an estimator's state holds (a higher carrier)")
    if delay_periods > MAX_DELAY_PERIODS:
        raise ValueError(f"the drive's delay of {delay_periods} periods is more than the {MAX_DELAY_PERIODS} an "
                         f"estimator's state holds")


SETTING_KEYS = (
    Key("frequency_Hz", "Hz", MIN_INJECTION_FREQUENCY_HZ, low_inclusive=True),
    Key("amplitude_V", "V", 0.0),
    Key("demodulation_amplitude", "", 0.0),
    Key("lowpass_Hz", "Hz", 0.0),
    Key("lowpass_order", "", 1, 8, low_inclusive=True, integer=True),
    Key("bandpass_Hz", "Hz", 0.0, doc="[low_Hz, high_Hz]"),
    Key("bandpass_order", "", 1, 8, low_inclusive=True, integer=True),
    Key("bandpass_ratio", "", 1.0),
    Key("pll_bandwidth_Hz", "Hz", 0.0),
    Key("speed_bandwidth_Hz", "Hz", 0.0),
    Key("observable_backemf_per_rated", "", 0.0, 1.0),
    Key("pll_damping", "", 0.0),
    Key("pll_type", "", choices=(2, 3, "auto")),
    Key("A_p", "", 0.0, nullable=True),
    Key("T_i_s", "s", 0.0, nullable=True),
    Key("T_f_s", "s", 0.0),
    Key("u_star", "", 0.0),
    Key("observable_ratio", "", 0.0, 1.0, low_inclusive=True, high_inclusive=False),
    Key("demodulation", "", choices=("paper", "aligned")),
    Key("dither_rad", "rad", 0.0, math.pi / 4.0),
    Key("samples_per_half_period", "", 1, 100, low_inclusive=True, integer=True),
    Key("signal_smoothing_Hz", "Hz", 0.0),
    Key("dead_time_model", "", choices=(True, False, "auto")),
    Key("saliency_snr_min", "", 0.0, low_inclusive=True),
    Key("align_tolerance_rad", "rad", 0.0, 1.0),
    Key("settle_s", "s", 0.0, 1.0, low_inclusive=True),
    Key("align_timeout_s", "s", 0.0, 10.0),
    Key("quiet_s", "s", 0.0, 1.0, low_inclusive=True),
    Key("pulse_current_per_rated", "", 0.0, 1.0),
    Key("pulse_s", "s", 0.0, 0.01),
    Key("pulse_sequences", "", 1, 100, low_inclusive=True, integer=True),
    Key("polarity_margin", "", 0.0, 0.5),
    Key("polarity_tries", "", 1, 100, low_inclusive=True, integer=True),
    Key("run_refused", "", choices=(True, False)),
    Key("injection_by_rule", "", choices=(True, False)),
    Key("flush_s", "s", 0.0, 1.0, low_inclusive=True),
    Key("lock_filter_Hz", "Hz", 0.0),
    Key("lock_persist_s", "s", 0.0, 1.0),
    Key("lost_hold_s", "s", 0.0, 1.0, low_inclusive=True),
    Key("max_restarts", "", 0, 100, low_inclusive=True, integer=True),
    Key("backemf_polarity_ratio", "", 0.0),
    Key("polarity_from_recording", "", choices=(True, False)),
    *(Key(name, "", 0.0) for name in ("handover_backemf_ratio", "handback_backemf_ratio", "quiet_backemf_ratio",
                                      "inject_backemf_ratio")),
    *(Key(name, "rad" if name.endswith("_rad") else "s", 0.0, 1.0)
      for name in ("agreement_rad", "disagreement_rad", "agreement_s", "blend_s", "fade_s", "ready_s", "lookahead_s")),
)
"""Every estimator setting, declared once (drive_common.contract.settings.Key); an estimator's defaults
name the ones it takes."""
SETTING = {key.name: key for key in SETTING_KEYS}
BELOW_NYQUIST = ("frequency_Hz", "lowpass_Hz", "bandpass_Hz", "pll_bandwidth_Hz", "speed_bandwidth_Hz",
                 "signal_smoothing_Hz", "lock_filter_Hz")
"""The settings also bounded by the sampling's Nyquist frequency, 0.5/T_s (exclusive)."""


def read_setting(name, value, T_s):
    """The setting ``name``'s ``value`` read through its Key (a frequency below Nyquist at ``T_s`` [s],
    ``bandpass_Hz`` a pair of edges, low below high); ValueError naming the key."""
    key = SETTING[name]
    if name in BELOW_NYQUIST:
        key = dataclasses.replace(key, high=0.5 / T_s, high_inclusive=False)
    if name == "bandpass_Hz":
        if not isinstance(value, (list, tuple)) or len(value) != 2:
            raise ValueError(f"{name}: must be [low_Hz, high_Hz], not {shown(value)}")
        low, high = (key.read(v) for v in value)
        if low >= high:
            raise ValueError(f"{name}: the low edge must lie below the high one, not {shown(value)}")
        return [low, high]
    return None if value is None and key.nullable else key.read(value)


def check_settings(name, settings, defaults, T_s):
    """Defaults overridden by settings, each value read through its Key (read_setting); KeyError for an unknown key,
    ValueError for an unusable value, each naming the estimator and the key."""
    unknown = set(settings) - set(defaults)
    if unknown:
        raise KeyError(f"estimator '{name}': unknown setting(s) {', '.join(sorted(map(str, unknown)))} "
                       f"(known: {', '.join(sorted(defaults))})")
    merged = dict(defaults)
    merged.update(settings)
    try:
        return {key: read_setting(key, value, T_s) for key, value in merged.items()}
    except ValueError as error:
        raise ValueError(f"estimator '{name}': {error}") from None
