"""The controller a scenario configures, for its motor's nameplate and the estimator it runs with."""
import math
from typing import NamedTuple

from drive_common.config.scenario import ScenarioError
from drive_common.motor.open_loop_start import ESTIMATOR as OPEN_LOOP_ESTIMATOR
from drive_common.motor.scaled_loops import scaled_loops
from drive_common.motor.torque_limit import MtpaPath, current_bound, sensorless_torque

from .params import check_settings, make_controller_params, speed_loop_plant
from .protection import make_protection_params
from .speed_margin import SpeedEstimate, SpeedLoopPlant, TrackingLoop
from .tuning import PIGains, speed_bandwidth_damping


def check_controller_settings(scenario):
    """Validate the scenario's controller settings before the estimator is known; ScenarioError names
    the scenario and the key."""
    try:
        check_settings(scenario.controller, scenario.T_s)
    except (KeyError, ValueError) as error:
        raise ScenarioError(f"{scenario.source_of('controller')}: {error.args[0]}") from None


def controller_for_scenario(scenario, injection_frequency_Hz, tracking_bandwidth_Hz, tracking_current_limit_A,
                            commissioning, tracking_acceleration_rad_s2=math.inf, tracking_loop=None):
    """ControllerParams for ``scenario`` with an estimator that injects at ``injection_frequency_Hz`` (0:
    none), tracks with ``tracking_bandwidth_Hz`` and holds its angle up to ``tracking_current_limit_A``
    (None: no limit of its own); the scenario's current_limit_A overrides that limit. The current loops
    use the ``commissioning`` record's R_s; ψ_f and J are the rotating test's where it ran; its delay is the
    answer delay plus the blocks' N − 1; the speed loop's bandwidth is scaled to the motor
    (drive_common.motor.scaled_loops) unless the scenario sets it, and the speed reference ramped within the
    electrical acceleration ``tracking_acceleration_rad_s2`` the estimator follows (rule 4 there; ∞: none) unless
    the scenario sets its ``speed_ramp_rad_s2``; the speed loop keeps its margins on the estimator's
    ``tracking_loop`` (hf_estimator.interface.Estimator.tracking_loop; None: assumed from its bandwidth)."""
    plate = commissioning.refined(scenario.motor.nameplate)
    if not math.isfinite(plate.J_kgm2):
        raise ScenarioError(f"{scenario.motor.given_by}: {scenario.motor.source}: nameplate.J_kgm2: unknown, and the "
                            f"commissioning has not measured it: the speed loop cannot be tuned (give J_kgm2, or "
                            f"`drive commission --rotating` measures it)")
    settings = dict(scenario.controller)
    settings.setdefault("speed_bandwidth_rad_s",
                        scaled_loops(plate, scenario.motor.inverter, scenario.T_s).speed_bandwidth_rad_s)
    if tracking_current_limit_A is not None:
        settings.setdefault("current_limit_A", tracking_current_limit_A)
    settings.setdefault("speed_ramp_rad_s2", tracking_acceleration_rad_s2 / plate.n_p)
    try:
        return make_controller_params(plate, loop_inverter(scenario), scenario.T_s, settings, injection_frequency_Hz,
                                      speed_estimate(tracking_bandwidth_Hz, tracking_loop), commissioning,
                                      scenario.estimator == OPEN_LOOP_ESTIMATOR)
    except (KeyError, ValueError) as error:
        raise ScenarioError(f"{scenario.source_of('controller')}: {error.args[0]}") from None


def loop_inverter(scenario):
    """``scenario``'s inverter with the whole delay its loops see: the answer delay plus the blocks' N − 1."""
    return scenario.motor.inverter._replace(delay_periods=scenario.answer_delay_periods() + scenario.block_samples - 1)


def speed_estimate(tracking_bandwidth_Hz, tracking_loop):
    """speed_margin.SpeedEstimate of an estimator's tracking bandwidth [Hz] and its stated ``tracking_loop`` (the
    four numbers of its facts, None where it states none)."""
    return SpeedEstimate(tracking_bandwidth_Hz, None if tracking_loop is None else TrackingLoop(*tracking_loop))


class SpeedLoop(NamedTuple):
    """A built drive's speed loop: its ``plant`` (speed_margin.SpeedLoopPlant), its PI's ω_n [rad/s] and ζ."""

    plant: SpeedLoopPlant
    omega_n_rad_s: float
    damping: float


def speed_loop(scenario, commissioning, controller, estimator_facts):
    """The SpeedLoop ``controller`` (ControllerParams, built by controller_for_scenario for ``scenario`` and
    ``commissioning``) closes on the estimator of ``estimator_facts`` (Estimator.facts(), as the nodes read them)."""
    motor = commissioning.refined(scenario.motor.nameplate)._replace(R_s_ohm=controller.R_s_ohm)
    plant = speed_loop_plant(motor, loop_inverter(scenario), scenario.T_s, PIGains(controller.kp_q, controller.ki_q),
                             controller.speed_filter_gain, speed_estimate(estimator_facts["tracking_bandwidth_Hz"],
                                                                          estimator_facts["tracking_loop"]))
    omega_n, damping = speed_bandwidth_damping(plant.J_kgm2, plant.B_Nms, plant.k_t_Nm_per_A,
                                               PIGains(controller.kp_speed, controller.ki_speed))
    return SpeedLoop(plant, omega_n, damping)


def stated_torque(scenario, commissioning, controller, injecting, estimator_bound=None):
    """The SensorlessTorque the drive of ``scenario`` states before it runs (drive_common.motor.torque_limit): the
    torque at the ``controller``'s (ControllerParams) current limit on its current path, and what set that
    limit (the estimator's own ``estimator_bound``, its facts' tracking_current_bound; the ``commissioning``'s
    tables where the estimator is ``injecting``; the bus; the nameplate)."""
    plate = commissioning.refined(scenario.motor.nameplate)
    path = (MtpaPath(controller.mtpa_current_A, controller.mtpa_d_current_A, math.nan)
            if controller.mtpa_current_A.shape[0] else None)
    bound = current_bound(plate, commissioning, scenario.motor.inverter, controller.i_max_A, injecting,
                          estimator_bound)
    return sensorless_torque(plate, commissioning, controller.i_max_A, path, bound)


def protection_for_scenario(scenario, commissioning, current_limit_A=None, bus_measured=True):
    """ProtectionParams of ``scenario``'s drive (foc_controller.protection: its ``protection`` figures or
    their defaults, the motor's inverter rating, the ``commissioning`` record's R_s; ScenarioError naming
    the file and the key of a figure refused), folding back from ``current_limit_A`` (the
    controller's; None: the nameplate's). A drive that does not measure its bus (``bus_measured`` False:
    the ROS graph's nodes, whose topics carry no DC-link voltage) takes it as the rated one, so a motor
    whose link can rise (inverter.C_dc_F finite) is refused there, naming the key."""
    motor = scenario.motor
    if not bus_measured and math.isfinite(motor.inverter.C_dc_F):
        raise ScenarioError(f"{motor.given_by}: {motor.source}: inverter.C_dc_F: {motor.inverter.C_dc_F:g} F: the ROS "
                            f"graph's topics carry no DC-link voltage, so its drive cannot protect a link that rises "
                            f"(run it with `drive run` or `drive bridge`, docs/protections.md)")
    try:
        protection = make_protection_params(motor.nameplate, motor.inverter, scenario.T_s, scenario.protection,
                                            commissioning)
    except ValueError as error:
        raise ScenarioError(f"{scenario.source_of('protection')}: {error}") from None
    return protection if current_limit_A is None else protection._replace(current_limit_A=current_limit_A)
