"""The inverse side: the object's motion → joint motion → torques, their distribution among the arms,
the internal wrench and object stress, and the dynamic load carrying capacity.

    trajectory.py     object-motion trajectories and the closed-chain IK of every arm
    path.py           the geometric object path p(s), R(s) and the closed-chain joint path θ(s) along it
    retime.py         fixed path, free timing: the minimum-time law of a payload, the heaviest payload in a
                      duration (TOPP-RA reachability and one LP over the grid; eq. 36 lines exact)
    retime_weights.py the minimum energy's weights Q optimised with its time law, in turn
    problem.py        the inverse-dynamics problem along a trajectory (eqs. 28–32) and its result
    distributions.py  the redundancy resolutions' kernels: paper W⁺, non-squeezing, minimum energy
                      (eqs. 33–35), bounded; the internal wrench
    solve.py          a resolution chosen by name, distributed at every sample, resolved torques
    replay.py         resolved torques fed back through the forward model
    lp_replay.py      the LP bound's grasp wrenches between its grid points, for the optimum's replay
    resolutions.py    the registry of redundancy resolutions (paper W⁺, non-squeezing, minimum energy,
                      bounded)
    qp.py             the small QPs and LPs (bounded resolution, the LP bound)
    stress.py         section loads and stress in the object
    capacity.py       the DLCC (eq. 36 motor lines), closed form per linear resolution and the LP bound
    spline_path.py    a free-form object path: B-splines in position and rotation vector between two poses
    free_path.py      the B-spline path between two poses that carries the most (an NLP, SLSQP)
"""
