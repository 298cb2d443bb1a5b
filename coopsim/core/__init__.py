"""The data and vocabulary every layer shares; imports NumPy only.

    model.py    the frozen `Model` (arms, object, motors, settings) and torque sources
    joints.py   revolute and prismatic joints: transform, motion subspace, units
    spatial.py  rotations, cross products, rigid-body kinematics helpers
    errors.py   CoopsimError and the errors and warnings every layer raises
    results.py  sampled motions and projections shared by the engines and both sides
    labels.py   the names of arms and joints in messages and figures
    tableaux.py the integrators' Butcher tableaux and dense-output coefficients (one copy for both engines)
    digest.py   content digests: a value's identity by what it holds (results shared between sweep points)
"""
