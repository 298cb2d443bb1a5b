"""The errors and warnings every layer raises: each error is reported to a user as one line."""


class CoopsimError(Exception):
    """Base class of every error coopsim reports to a user as one line."""


class ScenarioError(CoopsimError):
    """A scenario that cannot be turned into a model; the message names the field."""


class ConstraintError(CoopsimError):
    """The closed chain cannot be solved (singular mass or constraint matrix, unreachable loop)."""


class SimulationError(CoopsimError):
    """The simulation stopped; the message gives the time, the configuration and the reason."""


class ConstraintRankWarning(RuntimeWarning):
    """The constraint matrix Λ𝐈⁻¹Λᵀ lost rank; grasp wrenches are the minimum-norm ones."""
