"""Every motor value the drive uses, with where it came from: the nameplate, the commissioning file,
or a default (published in drive_config and printed by `drive run`)."""
from .commissioning import SCALARS, TABLES

NAMEPLATE_VALUES = ("n_p", "psi_f_Wb", "rated_current_A", "rated_speed_rpm", "rated_torque_Nm", "current_limit_A",
                    "J_kgm2", "B_Nms")


def motor_knowledge(plate, commissioning):
    """{key: {"value": ..., "source": ...}} of the nameplate values the drive reads (NAMEPLATE_VALUES, ψ_f
    and J the rotating test's where it ran) and of the commissioning record (its scalars; its tables by
    their length)."""
    knowledge = {key: {"value": getattr(plate, key), "source": "nameplate"} for key in NAMEPLATE_VALUES}
    for key, value in commissioning.rotating_values().items():
        knowledge[key] = {"value": value, "source": f"commissioning file {commissioning.source} (rotating test)"}
    sources = commissioning.sources()
    for key in SCALARS:
        knowledge[key] = {"value": float(getattr(commissioning, key)), "source": sources[key]}
    for key in TABLES:
        knowledge[key] = {"value": f"{len(getattr(commissioning, key))} points", "source": sources[key]}
    return knowledge
