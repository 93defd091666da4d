"""rig.sim — the simulator: the effect catalog (`effects`, one module per stage: world,
TDOA, IMU, timing), trajectories (`trajectory`), and `simulate` (a flight from a config),
`inject` (a recording as if effects had been present) and the `Predictor` (what the
simulator's physics predicts along a recording's ground truth, used by the diagnosis).

May import: `rig.data`, and `rig.estimator` (the learned-bias effect evaluates the
estimator's own bias network and feature code).
"""
