"""The estimator a scenario names, built for its motor's nameplate and a commissioning record."""
import dataclasses

from drive_scenarios.scenario import ScenarioError
from motor_params.commissioning import MIN_CONVERGENCE_SLOPE
from motor_params.nameplate import nameplate

from .interface import injects
from .registry import make_estimator


def estimator_for_scenario(scenario, commissioning):
    """A fresh Estimator for ``scenario`` (its estimator, settings and injection; θ̂ = 0) on a
    motor with this ``commissioning`` record; an injecting estimator carries the current up to which its
    angle information holds. ScenarioError names the scenario and the key at fault."""
    plate = nameplate(scenario.motor)
    try:
        settings = dict(scenario.estimator_settings)
        limit = None
        if injects(scenario.estimator):
            settings = {**scenario.injection, **settings}
            limit = commissioning.tracking_current_limit_A(MIN_CONVERGENCE_SLOPE)
        estimator = make_estimator(scenario.estimator, plate, scenario.T_s, settings, commissioning,
                                   scenario.drive_delay_periods())
    except KeyError as error:
        raise ScenarioError(f"{scenario.estimator_source}: {error.args[0]}") from None
    except ValueError as error:
        raise ScenarioError(f"{scenario.source}: estimator: {error.args[0]}") from None
    return dataclasses.replace(estimator, tracking_current_limit_A=limit)
