"""coopsim: cooperative-manipulator closed-chain dynamics, validated against MuJoCo.

The public face, for scripts and notebooks (each name is imported from its module on first use, so
`import coopsim` stays light and a command loads only what it runs):

    load_scenario, model_from_dict     a scenario file or its data → frozen `Model` (coopsim.io.scenario)
    Model, TorqueTable, TorqueFunction, TorqueFeedback, LoopController
                                       the model and its torque sources (coopsim.core.model)
    CoopsimError, ScenarioError, ConstraintError, SimulationError
                                       the errors (coopsim.core.errors)
    simulate, SimResult                the forward pipeline (coopsim.forward.simulate)
    closed_loop, Controller            a scenario's controller in the loop (coopsim.control.controller)
    cross_validate                     native model against the MuJoCo twin (coopsim.twin.harness)
    object_motion_trajectory           an object motion → joint trajectory (coopsim.inverse.trajectory)
    inverse_problem, resolution_for, resolve
                                       inverse dynamics with a redundancy resolution (coopsim.inverse)
    inverse_study, capacity_study      a scenario's whole inverse and capacity study, as the commands run
                                       them (coopsim.report.inverse_report)
"""

from importlib import import_module as _import_module
from importlib.metadata import PackageNotFoundError as _NotFound, version as _version

try:
    __version__ = _version("coopsim")
except _NotFound:   # a source tree that is not installed
    __version__ = "unknown"

_PUBLIC = {
    "load_scenario": "coopsim.io.scenario", "model_from_dict": "coopsim.io.scenario",
    "Model": "coopsim.core.model", "TorqueTable": "coopsim.core.model", "TorqueFunction": "coopsim.core.model",
    "TorqueFeedback": "coopsim.core.model", "LoopController": "coopsim.core.model",
    "CoopsimError": "coopsim.core.errors", "ScenarioError": "coopsim.core.errors",
    "ConstraintError": "coopsim.core.errors", "SimulationError": "coopsim.core.errors",
    "simulate": "coopsim.forward.simulate", "SimResult": "coopsim.forward.simulate",
    "closed_loop": "coopsim.control.controller", "Controller": "coopsim.control.controller",
    "cross_validate": "coopsim.twin.harness",
    "object_motion_trajectory": "coopsim.inverse.trajectory",
    "inverse_problem": "coopsim.inverse.problem", "resolution_for": "coopsim.inverse.solve",
    "resolve": "coopsim.inverse.solve",
    "inverse_study": "coopsim.report.inverse_report", "capacity_study": "coopsim.report.inverse_report",
}
__all__ = ["__version__", *_PUBLIC]


def __getattr__(name: str):
    """A public name, imported from its module on first use (PEP 562)."""
    module = _PUBLIC.get(name)
    if module is None:
        raise AttributeError(f"module 'coopsim' has no attribute {name!r}")
    value = getattr(_import_module(module), name)
    globals()[name] = value
    return value


def __dir__():
    return sorted(set(globals()) | set(_PUBLIC))
