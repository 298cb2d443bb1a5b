"""Controllers in the loop: control laws over the scenario's `control:` section, closing the loop
around the forward pipeline (a torque source for `coopsim.forward.simulate`).

    controller.py  joint PD with gravity/bias compensation, object-space computed torque, squeeze,
                   grasp-error feedback, eq. 36 saturation (compiled: `coopsim.compiled.control`)
"""
