"""The estimator a scenario names, built for its motor's nameplate and a commissioning record, with the
loops scaled to the motor (drive_common.motor.scaled_loops) where the scenario does not set them."""
import dataclasses
import math

import numpy as np

from drive_common.config.scenario import ScenarioError
from drive_common.motor.commissioning import MIN_CONVERGENCE_SLOPE
from drive_common.motor.open_loop_start import ESTIMATOR as OPEN_LOOP_ESTIMATOR
from drive_common.motor.scaled_loops import (
    CARRIER_PER_TRACKING,
    SPEED_RAMP_LAG_RAD,
    scaled_loops,
    tracked_acceleration_e_rad_s2,
)
from drive_common.motor.torque_limit import BOUNDS, estimator_commissioning

from .if_observer import below_speed_refusal, plan_for
from .interface import injects
from .pll_model import (
    PEAK_PER_RMS,
    TARGET_PEAK_RAD,
    TARGET_RMS_RAD,
    injection_frame_noise_gain,
    predicted_angle_error_rad,
)
from .registry import make_estimator
from .square_wave import square_wave_predicted_error, square_wave_serves
from .torque_polarity import torque_polarity_note

SCALED_TRACKING = ("injection_frame", "full_speed")
"""Ours: the tracking bandwidth, carrier and amplitude follow the motor (scaled_loops) unless set; the
papers' estimators keep their papers' carrier and loop unless set (only the bus caps their amplitude)."""
OWN_CARRIER = ("square_wave",)
"""Its carrier, amplitude and tracking follow its own rules (hf_estimator.square_wave); a scenario's sine
carrier is not its."""
RAMPED = ("injection_frame", "square_wave")
"""Ours whose injection leads over the whole speed range: the controller ramps the speed reference within the
acceleration its tracking follows (drive_common.motor.scaled_loops, rule 4)."""


def scaled_tracking(name, loops, injection_frequency_Hz=math.inf):
    """The tracking settings of ours (SCALED_TRACKING: ``name``) on the loops scaled to the motor (ScaledLoops):
    its PLL bandwidth [Hz], within a carrier of ``injection_frequency_Hz`` (CARRIER_PER_TRACKING carrier periods per
    tracking period), and the acceleration-limited loop where the rotor's rated acceleration outruns it;
    {} for another estimator (it keeps its paper's)."""
    if name not in SCALED_TRACKING:
        return {}
    scaled = {"pll_bandwidth_Hz": min(loops.tracking_bandwidth_Hz, injection_frequency_Hz / CARRIER_PER_TRACKING)}
    if name == "injection_frame" and loops.acceleration_limited:
        scaled["pll_type"] = "auto"
    return scaled


def scaled_injection(scenario, plate):
    """(estimator settings with the loops scaled to the motor known by ``plate`` (its nameplate, refined by
    the commissioning) and the bus cap applied, what the drive says of them: a list of lines)."""
    loops = scaled_loops(plate, scenario.motor.inverter, scenario.T_s)
    settings = dict(scenario.estimator_settings)
    if not injects(scenario.estimator):
        return settings, []
    notes = list(loops.notes) if scenario.estimator in SCALED_TRACKING else []
    injection = {} if scenario.estimator in OWN_CARRIER else dict(scenario.injection)
    if scenario.written_for and injection:
        given = ", ".join(f"{key} {value:g}" for key, value in sorted(injection.items()))
        if scenario.estimator in SCALED_TRACKING:
            notes.append(f"the scenario's injection ({given}) is {scenario.written_for}'s; on "
                         f"{scenario.motor.name} ours takes the carrier and loops scaled to it")
            injection = {}
        else:
            notes.append(f"{scenario.estimator} keeps its paper's injection ({given}) and loop on "
                         f"{scenario.motor.name}: the method as published, written for {scenario.written_for}")
    if scenario.estimator in SCALED_TRACKING:
        injection = {"frequency_Hz": loops.injection_frequency_Hz, "amplitude_V": loops.injection_amplitude_V,
                     **injection}
        settings = {**scaled_tracking(scenario.estimator, loops), **settings}
    settings = {**injection, **settings}
    amplitude = settings.get("amplitude_V")
    if isinstance(amplitude, (int, float)) and amplitude > loops.amplitude_cap_V:
        settings["amplitude_V"] = loops.amplitude_cap_V
        notes.append(f"injection amplitude {amplitude:g} V held to {loops.amplitude_cap_V:.3g} V: "
                     f"{scenario.motor.inverter.U_dc_V:g} V bus")
    return settings, notes


def _blamed(scenario, message):
    """An estimator's refusal (``estimator 'NAME': KEY: …``) as the scenario's key that set the value: its
    ``injection.KEY`` where the injection gave it, else its ``estimator``, in the file that gave the key."""
    parts = message.split(": ", 2)
    if len(parts) == 3 and parts[1] in scenario.injection and parts[1] not in scenario.estimator_settings:
        return f"{scenario.source_of('injection')}: injection.{parts[1]}: {parts[2]}"
    return f"{scenario.source_of('estimator')}: estimator: {message}"


PREDICTED = (*SCALED_TRACKING, "square_wave")
"""The estimators whose angle error the drive predicts before running (and refuses on)."""


def predicted_error(estimator, commissioning):
    """(RMS, peak) [rad] of the noise-driven angle error at no load predicted before running from the
    commissioned saliency and sensor noise and the estimator's loop (pll_model.predicted_angle_error_rad; the
    square wave's: square_wave.square_wave_predicted_error), and the saliency current I_Δ [A]; None for another
    estimator, or where the noise or the saliency is not measured."""
    p = getattr(estimator.params, "hf", estimator.params)
    if estimator.name not in PREDICTED or commissioning.sensor_noise_A <= 0.0 or not commissioning.salient():
        return None
    if estimator.name == "square_wave":
        return square_wave_predicted_error(p, commissioning.sensor_noise_A)
    omega_h = 2.0 * math.pi / (p.N * p.T_s_s)
    current = p.injection_amplitude_V * abs(commissioning.delta) / omega_h
    gain = injection_frame_noise_gain((p.kp, p.ki, p.ka), 2 * p.N, p.delay_periods, p.T_s_s)
    rms = predicted_angle_error_rad(current, commissioning.sensor_noise_A, gain, p.N)
    return rms, PEAK_PER_RMS * rms, current


LOADED_ERROR_SHARE = 0.75
"""Under load ours keeps its predicted noise-driven angle error (loaded_predicted_rms) within this share of the
RMS target; the rest is left to what the prediction leaves out under load: a mean error from the dead time and the
saliency's turn, 0.01-0.04 rad on drawn weakly salient rotors (docs/results.md "Random motors"). A motor whose
no-load prediction already takes more than the share keeps the target itself."""
PREDICTION_POINTS = 201
"""Currents searched, evenly from zero to the tables' limit, for predicted_current_limit."""


def signal_kept(commissioning, current_A):
    """(share of its no-load |Δ|/Σ the saliency keeps, convergence slope F) at q current ±``current_A`` [A], each
    the smaller of the two signs (Commissioning.saliency_retained, the commissioned slope table)."""
    currents, slope = commissioning.saliency_shift_i_q_A, commissioning.convergence_slope
    F = min(float(np.interp(current_A, currents, slope)), float(np.interp(-current_A, currents, slope)))
    return commissioning.saliency_retained(current_A), F


def loaded_predicted_rms(rms_rad, commissioning, current_A):
    """Ours' predicted angle error RMS [rad] at q current ±``current_A`` [A] from its no-load prediction ``rms_rad``:
    the saliency current falls with |Δ|/Σ and the error signal's slope with F (signal_kept), each dividing the
    angle the same noise gives."""
    retained, F = signal_kept(commissioning, current_A)
    kept = retained * F
    return rms_rad / kept if kept > 0.0 else math.inf


def predicted_current_limit(predicted, commissioning, limit_A):
    """(current [A], why) up to which ours' loaded_predicted_rms, from the no-load ``predicted`` (predicted_error's),
    stays within LOADED_ERROR_SHARE of the RMS target (the target itself where the no-load prediction exceeds that
    share), where that is below ``limit_A`` (the commissioned tables' limit); None where it is not, where the drive
    predicts no error, or where the no-load prediction misses the target (refused_signal speaks for that)."""
    if predicted is None or not math.isfinite(predicted[0]) or not limit_A > 0.0:
        return None
    rms = predicted[0]
    allowed = TARGET_RMS_RAD * (LOADED_ERROR_SHARE if rms <= LOADED_ERROR_SHARE * TARGET_RMS_RAD else 1.0)
    currents = np.linspace(0.0, limit_A, PREDICTION_POINTS)
    errors = np.array([loaded_predicted_rms(rms, commissioning, i) for i in currents])
    beyond = np.flatnonzero(errors > allowed)
    if beyond.size == 0 or beyond[0] == 0:
        return None
    j = int(beyond[0])
    current = float(currents[j - 1] + (currents[j] - currents[j - 1]) * (
        allowed - errors[j - 1]) / (errors[j] - errors[j - 1]))
    retained, F = signal_kept(commissioning, current)
    why = (f"{rms:.3g} rad RMS predicted at no load reaches {allowed:.3g} rad there, the saliency at "
           f"{100.0 * retained:.0f} % of its no-load |Δ|/Σ and the error signal's slope F at {F:.2f}")
    return current, why


def refusable(name):
    """Whether the estimator ``name`` may refuse a motor or a scenario before running and takes the setting
    ``run_refused`` (`drive run --force`): the injecting ones (their predicted error, the polarity) and the
    I-f start (its speed)."""
    return injects(name) or name == OPEN_LOOP_ESTIMATOR


def refused_signal(predicted, estimator, commissioning, run_refused):
    """What the drive says of the ``estimator``'s ``predicted`` angle error (predicted_error's; "" within the
    targets): beyond TARGET_RMS_RAD or TARGET_PEAK_RAD, ValueError in one line (the predicted error, the target,
    the saliency figure) unless ``run_refused``, then a note."""
    if predicted is None or (predicted[0] <= TARGET_RMS_RAD and predicted[1] <= TARGET_PEAK_RAD):
        return ""
    rms, peak, current = predicted
    p = getattr(estimator.params, "hf", estimator.params)
    window = f"{p.half_period + 1} samples" if estimator.name == "square_wave" else f"its fit over {2 * p.N} samples"
    unsettled = (f"the {estimator.tracking_bandwidth_Hz:g} Hz tracking loop does not settle behind {window} and "
                 f"the drive's delay: " if not math.isfinite(rms) else "")
    problem = (f"{unsettled}predicted angle error {rms:.3f} rad RMS, {peak:.2f} rad peak against ours' targets "
               f"{TARGET_RMS_RAD:g} and {TARGET_PEAK_RAD:g} rad: saliency current {1e3 * current:.3g} mA (|Δ|/Σ "
               f"{abs(commissioning.delta / commissioning.sigma):.3f}) against "
               f"{1e3 * commissioning.sensor_noise_A:.3g} mA of sensor noise")
    if not run_refused:
        raise ValueError(f"{problem}; refused (`drive run --force` runs it anyway)")
    return f"run although refused ({problem})"


SALIENCY_REFUSALS = ("predicted angle error", "polarity cannot be told")
"""How ours' refusals for too little saliency begin (refused_signal; the start-up's polarity design)."""


def open_loop_offer(refusal, plate, commissioning, inverter):
    """What the drive offers a motor ours refuses for its saliency (``refusal``, its one line): the I-f start
    and the back-EMF observer above their speed, or why not (hf_estimator.if_observer); "" for another refusal."""
    if not any(kind in refusal for kind in SALIENCY_REFUSALS):
        return ""
    plan = plan_for(plate, commissioning, inverter)
    if plan.refused:
        return f"; nor can it start open loop: {plan.refused}"
    return f"; `estimator: {OPEN_LOOP_ESTIMATOR}` runs it without injection: {plan.statement(plate.n_p)}"


def below_speed(scenario, estimator, commissioning, run_refused):
    """An I-f start's refusal (hf_estimator.if_observer) of its motor (open_loop_start's) or of a scenario asking
    below its speed: ValueError in one line unless ``run_refused``, then a note; "" for another estimator or a
    scenario above the speed."""
    if estimator.name != OPEN_LOOP_ESTIMATOR:
        return ""
    plan = plan_for(commissioning.refined(scenario.motor.nameplate), commissioning, scenario.motor.inverter)
    refusal = plan.refused or below_speed_refusal(scenario, estimator.params.handover_rad_s)
    if refusal and not run_refused:
        raise ValueError(f"{refusal}; refused (`drive run --force` runs it anyway)")
    return f"run although refused ({refusal})" if refusal else ""


def _polarity_note(estimator):
    """What the drive says of its polarity test before running: the torque pulses' bounds where it uses them."""
    startup = getattr(getattr(estimator.params, "hf", estimator.params), "startup", None)
    return torque_polarity_note(startup) if startup is not None else ""


def chosen_estimator(scenario, plate, commissioning, inverter):
    """(the scenario with the estimator the loops' rule chooses, what the drive says of it): where ours runs with
    ``injection_by_rule`` (the motor's own experiments), the square wave where it serves the motor
    (square_wave.square_wave_serves, on ``plate``: the nameplate refined by the ``commissioning`` record, and
    ``inverter`` with the drive's delay), else ours' sine carrier; any other scenario as it is."""
    settings = dict(scenario.estimator_settings)
    if scenario.estimator != "injection_frame" or not settings.pop("injection_by_rule", False):
        return scenario, ""
    choice = square_wave_serves(plate, commissioning, inverter, scenario.T_s)
    name = "square_wave" if choice.serves else "injection_frame"
    chosen = dataclasses.replace(scenario, estimator=name, estimator_settings=settings)
    return chosen, f"the loops' rule: {'the square wave' if choice.serves else 'the sine carrier'} ({choice.reason})"


def drive_estimator(name, nameplate, T_s, settings, commissioning, inverter, controller_settings):
    """The estimator ``name`` (its checked ``settings``) as the drive builds it, in a run and in a replay of
    its recording: on the ``nameplate`` refined by the ``commissioning`` record, with the saliency shift of
    the current path the controller's ``controller_settings`` run (MTPA or i_d = 0), on ``inverter``
    (InverterRating with the drive's whole delay), sampled every T_s [s]."""
    plate = commissioning.refined(nameplate)
    return make_estimator(name, plate, T_s, settings, estimator_commissioning(plate, commissioning,
                                                                               controller_settings), inverter)


def _ramp_note(scenario, plate, tracking_bandwidth_Hz, acceleration_e_rad_s2):
    """What the drive says of its speed ramp (scaled_loops rule 4) where it binds below the rotor's acceleration at
    rated torque (``plate``: the nameplate refined by the commissioning), unless the scenario sets its own; "" else."""
    rated_e = plate.n_p * plate.rated_torque_Nm / plate.J_kgm2
    if "speed_ramp_rad_s2" in scenario.controller or not acceleration_e_rad_s2 < rated_e:
        return ""
    return (f"speed commands ramped at {acceleration_e_rad_s2 / plate.n_p:.3g} rad/s² (ours' "
            f"{tracking_bandwidth_Hz:.3g} Hz tracking follows that within {SPEED_RAMP_LAG_RAD:g} rad, where rated "
            f"torque would accelerate this rotor at {rated_e / plate.n_p:.3g} rad/s²)")


def estimator_for_scenario(scenario, commissioning):
    """A fresh Estimator for ``scenario`` (its estimator, settings and injection; θ̂ = 0) on a
    motor with this ``commissioning`` record; an injecting estimator carries the current up to which its
    angle information holds; the estimators run on the saliency shift of the controller's current path
    (drive_common.motor.torque_limit.estimator_commissioning). ScenarioError names the scenario and the key at fault."""
    plate = commissioning.refined(scenario.motor.nameplate)
    inverter = scenario.motor.inverter._replace(delay_periods=scenario.drive_delay_periods())
    try:
        scenario, chosen = chosen_estimator(scenario, plate, commissioning, inverter)
        settings, notes = scaled_injection(scenario, plate)
        notes = [chosen, *notes] if chosen else notes
        limit = None
        if injects(scenario.estimator):
            limit = commissioning.tracking_current_limit_A(MIN_CONVERGENCE_SLOPE)
        estimator = drive_estimator(scenario.estimator, scenario.motor.nameplate, scenario.T_s, settings,
                                    commissioning, inverter, scenario.controller)
        predicted = predicted_error(estimator, commissioning)
        notes += [n for n in (refused_signal(predicted, estimator, commissioning, bool(settings.get("run_refused"))),
                              below_speed(scenario, estimator, commissioning,
                                          bool(settings.get("run_refused")))) if n]
    except KeyError as error:
        raise ScenarioError(f"{scenario.estimator_source}: {error.args[0]}") from None
    except ValueError as error:
        raise ScenarioError(_blamed(scenario, error.args[0] + open_loop_offer(error.args[0], plate, commissioning,
                                                                              scenario.motor.inverter))) from None
    bound = None
    if injects(scenario.estimator):
        notes += [n for n in (commissioning.weak_saliency_note(), _polarity_note(estimator)) if n]
        loaded = predicted_current_limit(predicted, commissioning, limit)
        if loaded is not None:
            limit = loaded[0]
            bound = (BOUNDS[7], loaded[1], limit)
    acceleration = (tracked_acceleration_e_rad_s2(estimator.tracking_bandwidth_Hz)
                    if scenario.estimator in RAMPED else math.inf)
    notes += [n for n in (_ramp_note(scenario, plate, estimator.tracking_bandwidth_Hz, acceleration),) if n]
    note = "; ".join(n for n in (estimator.injection_note, *notes) if n)
    amplitude = estimator.injection_amplitude_V
    if amplitude is None and notes:
        amplitude = settings.get("amplitude_V")
    tracking_loop = estimator.tracking_loop
    if injects(scenario.estimator) and tracking_loop is not None:
        tracking_loop = (*tracking_loop[:4], *commissioning.convergence_slope_range(limit))
    return dataclasses.replace(estimator, tracking_current_limit_A=limit, tracking_current_bound=bound,
                               injection_note=note, tracking_loop=tracking_loop,
                               injection_amplitude_V=amplitude, settings=settings,
                               tracking_acceleration_rad_s2=acceleration)
