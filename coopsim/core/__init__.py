"""The data and vocabulary every layer shares; imports NumPy only.

    model.py    the frozen `Model` (arms, object, motors, settings) and torque sources
    joints.py   revolute and prismatic joints: transform, motion subspace, units
    spatial.py  rotations, cross products, rigid-body kinematics helpers
    results.py  sampled motions shared by the forward and inverse sides
    labels.py   the names of arms and joints in messages and figures
"""
