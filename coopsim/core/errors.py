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


def one_line(exc: BaseException, limit: int | None = None) -> str:
    """An exception's message as one line, for the reason part of a one-line error.

    Args:
        exc: the exception (or warning).
        limit: characters at most (longer: cut, ending in '...'); None: no limit.

    Returns:
        str: its text with every run of whitespace (line breaks included) made one space; the exception's
        type name when the text is empty.
    """
    reason = " ".join(str(exc).split()) or type(exc).__name__
    return reason if limit is None or len(reason) <= limit else reason[: limit - 3] + "..."
