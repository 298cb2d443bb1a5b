"""Compiled controllers in the loop (the laws of `coopsim.control.controller`, over flat arrays).

    record.py         PackedControl, its StructRef and constructors, the integer codes
    references.py     the joint trajectory and the object motion at time t
    distributions.py  the closed-chain inverse dynamics with a distribution, the squeeze
    laws.py           joint PD, computed torque, grasp feedback, the command; the entries

The time loop (`integrate.rhs`) calls `feedback` at every stage after the torque tables: the law's
command is added to the tabulated torques (a disturbance) and the sum clipped to the motor lines of
eq. 36 when `saturate` is set, exactly as `coopsim.control.controller.Controller.command` does in Python:

  * joint PD: u = Kp (θ_r − θ) + Kd (θ̇_r − θ̇) + τ_comp, θ_r a set-point or the quintic Hermite
    interpolant of a joint trajectory (`coopsim.inverse.trajectory.trajectory_at_times`), τ_comp the
    closed-chain inverse dynamics at (θ, 0, 0) or (θ, θ̇, 0) (`inverse_torques`);
  * computed torque: the object pose error e = [p_r − p; log(R_r Rᵀ)] and twist error against the
    prescribed object motion (`object_reference`, `coopsim.inverse.trajectory.object_motion_at`), the object
    acceleration a = a_r + Kd ė + Kp e, each arm's θ̈ from S J_m θ̈_m = S (a_EE,m − J̇_mθ̇_m), and the
    inverse dynamics of (θ, θ̇, θ̈) with a squeeze force in the null space of the grasp matrix;
    plus, per arm, joint-space feedback on its grasp error (`grasp_feedback`).

The inverse dynamics with a distribution, for the compensation and computed torque, is
`distributions.py`'s (the QP of 'bounded' is not compiled).

The controller evaluates its own model (`Pc`, `Wc`: the scene with the controller's object mass); every
array it writes is scratch of its `PackedControl`, so no evaluation allocates.
"""

from coopsim.compiled.control.laws import commands, evaluate, feedback
from coopsim.compiled.control.record import (CONTROL_SINGULAR, LAW_CUBIC, LAW_QUINTIC, PackedControl, control_struct,
                                             new_control)

__all__ = ["CONTROL_SINGULAR", "LAW_CUBIC", "LAW_QUINTIC", "PackedControl", "commands", "control_struct", "evaluate",
           "feedback", "new_control"]
