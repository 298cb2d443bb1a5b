"""Compiled native model (numba): the same algorithms as the plain-NumPy stages, over flat arrays.

The plain-NumPy modules (`coopsim.kinematics`, `gibbs_appell`, `grasp`, `closed_chain`, `manifold`,
`integrate`) are the readable reference; this package runs the same equations compiled, with no
Python and no allocation per evaluation, and is what the commands use. Stages, in the order they run:

    packing.py     Model → PackedModel (frozen arrays) and a Workspace of preallocated buffers
    linalg.py      small in-place factorizations (Cholesky, pivoted Cholesky, symmetric solves)
    spatial.py     3-vector / 3×3 helpers, rotation log, quaternion
    chain.py       kinematics → Gibbs–Appell arm terms → object/grasp terms → closed-chain solve
    manifold.py    loop-closure residual Φ, projection of positions and rates
    integrate.py   DOP853 / DOPRI5 (dense output) / RK4 time loop, torque tables, stabilization
    sample.py      every reported quantity at the output samples
    batch.py       many states (and many parameter sets) at once, in parallel
    api.py         the Python entry points and their error reporting

Tested against the reference stages at random states of every bundled scenario (≤ 1e-12 relative).
"""
