"""The inverse side: the object's motion → joint motion → torques, their distribution among the arms,
the internal wrench and object stress, and the dynamic load carrying capacity.

    trajectory.py   object-motion trajectories and the closed-chain IK of every arm
    solve.py        the inverse-dynamics problem (eqs. 28–32), the distributions, resolve, replay
    resolutions.py  the registry of redundancy resolutions (paper W⁺, non-squeezing, minimum energy,
                    bounded)
    qp.py           the small QPs and LPs (bounded resolution, the LP bound)
    stress.py       section loads and stress in the object
    capacity.py     the DLCC (eq. 36 motor lines), closed form per linear resolution and the LP bound
"""
