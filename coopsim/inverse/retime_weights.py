"""Energy weights optimised together with the time law (minimum energy, eq. 33, along a fixed path).

The minimum-energy torques depend on the weights Q; the heaviest load a path carries within T_max
depends on Q and on the time law. The two are optimised in turn, each round started from the last:

    Q₀ = the scenario's weights;  (μ₀, law₀) = `coopsim.inverse.retime.max_payload` with Q₀;
    Q_k = `coopsim.inverse.capacity.optimise_weights` along law_{k−1} (its grid points, both sides);
    (μ_k, law_k) = the retiming with Q_k; stop when μ_k gains less than REL_GAIN (0.1 %) over μ_{k−1}.

Along law_{k−1} the weights Q_k carry at least μ_{k−1} (Q_{k−1} is one of Nelder–Mead's starts), and
law_{k−1} stays admissible for the retiming with Q_k at that load, so μ_k ≥ μ_{k−1}: the payload never
drops (up to the retiming's linearisation tolerance, which the kept round guards: a round that does not
gain is not taken).
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from coopsim.core.model import Model
from coopsim.inverse.capacity import optimise_weights
from coopsim.inverse.path import JointPath
from coopsim.inverse.problem import InverseProblem, inverse_problem
from coopsim.inverse.retime import Retiming, TimeLaw, max_payload, path_dynamics
from coopsim.inverse.solve import resolution_for
from coopsim.inverse.trajectory import JointTrajectory

ROUNDS = 6            # the most weight optimisations
REL_GAIN = 1e-3       # a round is kept, and another tried, when it carries more than (1 + REL_GAIN) × the last


@dataclass(frozen=True, eq=False)
class WeightedLaw:
    """The energy weights and time law found together.

    Attributes:
        model: the Model with motors.energy_weight = `weights`.
        weights: (n,) the optimised energy weights (geometric mean 1 over the active joints; 1 on passive).
        mass: kg, the heaviest load within T_max with them.
        retiming: its Retiming.
        rounds: [(weights (n,), mass kg)] from the scenario's weights on, one per kept round.
    """

    model: Model
    weights: np.ndarray
    mass: float
    retiming: Retiming
    rounds: list


def with_weights(model: Model, weights: np.ndarray) -> Model:
    """The model whose energy weights are `weights` (what `path_dynamics` and the minimum energy read).

    Args:
        model: the Model.
        weights: (n,) the energy weights Q.

    Returns:
        Model: a copy with motors.energy_weight = weights.
    """
    return replace(model, motors=replace(model.motors, energy_weight=np.asarray(weights, dtype=float)))


def law_problem(model: Model, jp: JointPath, law: TimeLaw) -> InverseProblem:
    """The inverse problem along a retimed law at its grid points, each with the interval before it and
    the one after it (the rows `coopsim.inverse.retime` constrains): θ̇ = θ′√b, θ̈ = θ′a + θ″b.

    Args:
        model: the Model.
        jp: the JointPath of the law's grid (N points).
        law: the TimeLaw on that grid.

    Returns:
        InverseProblem: 2N samples, at each point its "before" side (a of the previous interval, 0 at the
        first point) then its "after" side; t each of the law's times twice.
    """
    from coopsim.compiled import api

    qd = np.repeat(jp.d1 * np.sqrt(np.maximum(law.b, 0.0))[:, None], 2, axis=0)
    before, after = np.append(0.0, law.a[:-1]), law.a
    acc = np.stack([before, after], axis=1).reshape(-1)[:, None]              # before, after, point by point
    q, d1, d2 = (np.repeat(x, 2, axis=0) for x in (jp.q, jp.d1, jp.d2))
    qdd = d1 * acc + d2 * np.repeat(law.b, 2)[:, None]
    traj = JointTrajectory(np.repeat(law.t, 2), q, qd, qdd, "object_motion")
    terms = api.inverse_terms(model, q, qd, qdd)
    return inverse_problem(model, traj, model.inverse.payload_position, terms=terms)


def weights_with_law(model: Model, jp: JointPath, duration: float, mode: str, field: str = "--duration",
                     names: list[str] | None = None, rounds: int = ROUNDS) -> WeightedLaw:
    """The minimum-energy weights and time law that carry the most along the path within `duration`.

    Args:
        model: the Model (its energy weights start the search).
        jp: the JointPath on the retiming grid.
        duration: s, T_max.
        mode: 'payload' or 'scaled'.
        field: the input that set the duration (for `max_payload`'s message).
        names: (n,) the joints' labels (for `max_payload`'s message).
        rounds: the most weight optimisations.

    Returns:
        WeightedLaw.

    Raises:
        coopsim.inverse.retime.RetimeError: as `max_payload` with the scenario's weights.
    """
    res = resolution_for(model, "min_energy")
    mass, r, _ = max_payload(path_dynamics(model, jp, "min_energy", mode), duration, field=field, names=names)
    best = WeightedLaw(model, np.asarray(res.weights, dtype=float), mass, r, [(res.weights.copy(), mass)])
    for _ in range(rounds):
        w, _cap = optimise_weights(law_problem(best.model, jp, best.retiming.law), replace(res, weights=best.weights),
                                   model.motors, mode)
        m = with_weights(model, w)
        mass, r, _ = max_payload(path_dynamics(m, jp, "min_energy", mode), duration, field=field, names=names)
        if not mass > best.mass * (1 + REL_GAIN):
            break
        best = WeightedLaw(m, w, mass, r, best.rounds + [(w.copy(), mass)])
    return best
