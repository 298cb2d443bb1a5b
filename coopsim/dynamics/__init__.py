"""The reference engine: the paper's stages in plain NumPy, one file per stage, readable first.

    kinematics.py    stage 1: arm poses, Jacobians, J̇θ̇ (eqs. 3, 9, 13)
    gibbs_appell.py  stage 2: recursive Gibbs–Appell arm terms I_m, −Re_m (eqs. 9–10)
    grasp.py         stage 3: grasp matrices, object Newton–Euler, internal wrench (eqs. 1–8, 11–13)
    closed_chain.py  stage 4: the grasp wrenches eliminated, θ̈(θ, θ̇, τ) (eqs. 14–27)
    manifold.py      stage 5: consistent initial state, projection, Baumgarte stabilization
    integrate.py     DOP853 / DOPRI5 / RK4, landing on every output time
    scene.py         the scene's geometry: grasp poses, the plane of motion, the constraint rows S

`coopsim.compiled` runs the same stages compiled; the tests hold the two together.
"""
