"""Controllers in the loop: control laws over the scenario's `control:` section, closing the loop
around the forward pipeline (a torque source for `coopsim.forward.simulate`).

    laws.py        the laws as pure functions: joint PD, computed torque's object and joint
                   accelerations, pose and grasp errors, grasp feedback, squeeze, eq. 36 saturation
    controller.py  the Controller: a scenario's control: section as a torque source in the loop
                   (its reference, compensation and distribution; compiled: `coopsim.compiled.control`),
                   `closed_loop`, `record`
"""
