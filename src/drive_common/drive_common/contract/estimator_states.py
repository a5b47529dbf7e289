"""The estimator's state codes, `estimator_state` z (contract v2, docs/drive-interface.md): what the
estimator says of its angle, and what the controller may do with it (docs/startup.md)."""

HOLD, ALIGNING, POLARITY, TRACKING, LOCK_LOST = 0, 1, 2, 3, 4
"""0 hold (tracking, the signal too weak: the estimate coasts), 1 aligning on the saliency, 2 polarity
test, 3 tracking (torque allowed), 4 lock lost (zero torque)."""
STATE_NAMES = {HOLD: "hold", ALIGNING: "aligning", POLARITY: "polarity test", TRACKING: "tracking",
               LOCK_LOST: "lock lost"}

LEADER_INJECTION, LEADER_BACKEMF, LEADER_ENCODER = 0, 1, 2
"""Which source the angle estimate follows, `estimator_blend` z: 0 HF injection, 1 the back-EMF observer,
2 an encoder (docs/drive-interface.md)."""
LEADER_NAMES = {LEADER_INJECTION: "injection", LEADER_BACKEMF: "back-EMF", LEADER_ENCODER: "encoder"}
