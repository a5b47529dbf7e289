"""The estimator's state codes, `estimator_state` z (contract v2, docs/drive-interface.md): what the
estimator says of its angle, and what the controller may do with it (docs/startup.md)."""

HOLD, ALIGNING, POLARITY, TRACKING, LOCK_LOST, OPEN_LOOP = 0, 1, 2, 3, 4, 5
"""0 hold (tracking, the signal too weak: the estimate coasts), 1 aligning on the saliency, 2 polarity
test, 3 tracking (torque allowed), 4 lock lost (zero torque), 5 open loop (the back-EMF observer below its
speed: the controller turns the current itself, I-f; drive_common.motor.open_loop_start)."""
STATE_NAMES = {HOLD: "hold", ALIGNING: "aligning", POLARITY: "polarity test", TRACKING: "tracking",
               LOCK_LOST: "lock lost",
               OPEN_LOOP: "open loop"}

LEADER_INJECTION, LEADER_BACKEMF, LEADER_ENCODER = 0, 1, 2
"""Which source the angle estimate follows, `estimator_blend` z: 0 HF injection, 1 the back-EMF observer,
2 an encoder (docs/drive-interface.md)."""
LEADER_NAMES = {LEADER_INJECTION: "injection", LEADER_BACKEMF: "back-EMF", LEADER_ENCODER: "encoder"}
