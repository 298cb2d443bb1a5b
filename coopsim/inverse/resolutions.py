"""The redundancy resolutions of the inverse dynamics: one registry that every reader uses.

Each resolution is one entry of RESOLUTIONS: its pure function (the net object wrench → grasp wrenches,
through the kernels of `coopsim.inverse.distributions`), its label and colour (plots), whether its distribution is
linear in the net wrench (then `coopsim.inverse.capacity.method_capacity` has a closed form; otherwise it is
refused with the entry's reason) and its line of CLI help. The inverse study runs METHODS, the capacity
study LINEAR_METHODS, `coopsim inverse --method` offers METHODS, and the plots take labels, colours and
order from here. Adding a resolution is adding an entry.

This module is light to import (the CLI builds its argument parser from it): the kernels are imported
when a resolution is first run.
"""

from __future__ import annotations

from typing import Callable, NamedTuple


def _paper(prob, y, res):
    from coopsim.inverse.distributions import paper_distribution

    return paper_distribution(prob, y), ()


def _nonsqueezing(prob, y, res):
    from coopsim.inverse.distributions import nonsqueezing_distribution, nonsqueezing_metric

    return nonsqueezing_distribution(prob, y, nonsqueezing_metric(prob, res.masses, res.inertias)), ()


def _min_energy(prob, y, res):
    from coopsim.inverse.distributions import min_energy_distribution

    return min_energy_distribution(prob, y, res.weights, res.passive), ()


def _bounded(prob, y, res):
    from coopsim.inverse.distributions import bounded_min_energy_distribution, nonsqueezing_metric

    failures: list = []
    f = bounded_min_energy_distribution(prob, y, res, nonsqueezing_metric(prob, res.masses, res.inertias), failures)
    return f, tuple(failures)


class ResolutionMethod(NamedTuple):
    """One redundancy resolution: its pure function and how the readers name and show it.

    Attributes:
        name: the method's name (the key of RESOLUTIONS, `coopsim inverse --method`).
        distribute: its pure function, distribute(prob, y, res) → (f, failures): grasp wrenches f (N, rk)
            [N; N·m] in the rows S, arm after arm, world axes, for the net object wrenches y (N, k) of an
            `coopsim.inverse.problem.InverseProblem` with the settings of a
            `coopsim.inverse.problem.Resolution`, and the samples it could not solve (SampleFailure tuple,
            nan in f).
        label: its name in plot legends.
        color: its matplotlib colour.
        linear: the distribution is linear in the net object wrench (fixed weights and virtual bodies), so
            the capacity has a closed form.
        nonlinear_why: why it has none (the capacity's refusal); empty for a linear one.
        help: its words in `coopsim inverse --help`.
    """

    name: str
    distribute: Callable
    label: str
    color: str
    linear: bool
    nonlinear_why: str
    help: str


RESOLUTIONS: dict[str, ResolutionMethod] = {m.name: m for m in (
    ResolutionMethod("paper", _paper, "zero internal (paper W⁺)", "tab:blue", True, "",
                     "zero internal force with the paper's W+ (eq. 30)"),
    ResolutionMethod("nonsqueezing", _nonsqueezing, "zero internal (non-squeezing)", "tab:green", True, "",
                     "Erhart-Hirche non-squeezing load distribution"),
    ResolutionMethod("min_energy", _min_energy, "minimum energy", "tab:red", True, "",
                     "weighted minimum energy (eqs. 33-35)"),
    ResolutionMethod("bounded", _bounded, "min. energy, bounded internal", "tab:purple", False,
                     "its internal-wrench bounds make it a QP whose torques are not affine in the carried mass",
                     "minimum energy with a bounded internal wrench"),
)}
METHODS = tuple(RESOLUTIONS)                                           # every resolution, in report order
LINEAR_METHODS = tuple(k for k, m in RESOLUTIONS.items() if m.linear)  # those with a closed-form capacity


def resolution_method(name: str) -> ResolutionMethod:
    """The registered resolution `name`.

    Args:
        name: a key of RESOLUTIONS ('paper', 'nonsqueezing', 'min_energy', 'bounded').

    Returns:
        ResolutionMethod: its registry entry.

    Raises:
        ValueError: an unknown name (the message names the known ones).
    """
    try:
        return RESOLUTIONS[name]
    except KeyError:
        raise ValueError(f"unknown method {name!r}; expected one of {', '.join(METHODS)}") from None


def methods_help() -> str:
    """'paper: …; nonsqueezing: …' — every resolution's help, for the CLI.

    Returns:
        str: each method's `help`, in registry order, joined by '; '.
    """
    return "; ".join(f"{k}: {m.help}" for k, m in RESOLUTIONS.items())
