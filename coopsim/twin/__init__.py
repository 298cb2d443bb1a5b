"""The MuJoCo twin: the same scenario as an MJCF model with weld constraints, run on the same torques,
and the agreement with the native model.

    mjcf.py        MjSpec → MJCF (`models/*.xml`), keyframe at the consistent state, the viewer
    mujoco_run.py  the twin run (RK4, the same torques or controller)
    compare.py     agreement metrics
    harness.py     the cross-validation harness (native and twin, compared, logged)
    weld.py        the welds' yield predicted from the native run, the automatic step, why a twin differs
"""
