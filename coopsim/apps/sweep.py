"""Parameter sweeps: the sweep file → a validated `Sweep` (points), and one point's evaluation (pure).

A sweep varies fields of one base scenario (`coopsim.io.overrides` paths) over a grid or a quasi-random
design and runs one study per point — the library calls of the single-run command, so a row holds the
numbers that command prints for the overridden scenario (`coopsim simulate --json`, `coopsim validate
--json`, `coopsim inverse --no-curve --json`, `coopsim capacity --json`, with `--set` per axis):

    name: paper_capacity_map                   # outputs go to out/NAME (default: the file's stem)
    scenario: ../paper_planar_2x3_carry.yaml   # relative to the sweep file
    set: {inverse.object_motion.output_dt: 0.05}        # fixed overrides of every point (optional)
    design: grid                  # grid (default: every combination, the first axis slowest) | sobol | halton
    samples: 64                   # sobol | halton: number of points
    seed: 1                       # sobol | halton: the scrambling's seed
    axes:
      - {path: inverse.payload.position[0], values: [-0.2, 0.0, 0.2]}      # grid: values ...
      - {path: inverse.payload.position[1], linspace: [-0.03, 0.03, 5]}    # ... or start, stop, count
      # sobol | halton: {path: ..., range: [low, high]}
    study: {kind: capacity, lp: true, optimise: false}  # simulate | validate | inverse | capacity
    plot: ["capacity.payload.*.mass_kg"]       # the columns to draw (default: the study's)

Rows are flat: `point` (0-based index), one column per axis (named by its path or `name`), `error`
(None, or the point's one-line error: the sweep goes on), then the study's columns — its summary
flattened to dotted names (`capacity.payload.min_energy.mass_kg`, `min_manipulability[0]`) and
filtered by the study's `columns` patterns (`*` matches any text; defaults `COLUMNS`). No I/O here except reading
the sweep and scenario files in `load_sweep`.
"""

from __future__ import annotations

import hashlib
import itertools
import json
import re
import warnings
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from coopsim.control.controller import closed_loop
from coopsim.core.errors import CoopsimError, ScenarioError, one_line
from coopsim.forward.simulate import simulate
from coopsim.inverse.resolutions import METHODS
from coopsim.io.fields import Section
from coopsim.io.overrides import apply_overrides, parse_path
from coopsim.io.scenario import model_from_dict, require_motor_limits
from coopsim.io.yaml_rules import load_yaml
from coopsim.report.inverse_report import add_checks, capacity_study, capacity_summary, inverse_summary, solve_study
from coopsim.report.summary import simulation_summary
from coopsim.twin.harness import cross_validate

KINDS = ("simulate", "validate", "inverse", "capacity")
DESIGNS = ("grid", "sobol", "halton")
MAX_POINTS = 1_000_000
COLUMNS = {   # the summary entries a row keeps, per study (patterns over the flattened names: `*` any text)
    "simulate": ("duration_s", "max_constraint_residual", "max_velocity_residual", "max_condition_number",
                 "max_internal_force_N", "min_manipulability[*]", "kinetic_energy.initial_J", "kinetic_energy.final_J",
                 "kinetic_energy.max_relative_change", "final_object_position_m[*]",
                 "initial_correction.max_abs_dq_rad", "warnings", "steps_accepted", "rhs_evaluations"),
    "validate": ("passed", "metrics.*.max"),
    "inverse": ("complete", "bounded.force_bound_N", "bounded.moment_bound_Nm", "methods.*.energy",
                "methods.*.max_torque_norm_Nm", "methods.*.internal.*.max_force_N",
                "methods.*.internal.*.max_moment_Nm",
                "methods.*.stress.peak_normal_Pa", "methods.*.stress.peak_shear_Pa", "methods.*.replay.*"),
    "capacity": ("capacity.*.mass_kg", "capacity.*.saturating_motor", "capacity.*.line", "capacity.*.time_s",
                 "capacity.*.feasible", "lp_bound.*.mass_kg", "lp_bound.*.saturating_motor", "lp_bound.*.feasible",
                 "optimised_weights.mass_kg", "optimised_weights.saturating_motor", "energy.*"),
}
PLOTS = {     # the columns drawn by default
    "simulate": ("max_internal_force_N", "kinetic_energy.max_relative_change"),
    "validate": ("metrics.joint_angle_error.max", "metrics.object_position_error.max"),
    "inverse": ("methods.*.energy", "methods.min_energy.internal.nonsqueezing.max_force_N",
                "methods.min_energy.stress.peak_normal_Pa"),
    "capacity": ("capacity.*.mass_kg", "lp_bound.*.mass_kg"),
}


@dataclass(frozen=True)
class Study:
    """What runs at each point of a sweep: one study of the single-run commands.

    Attributes:
        kind: the study, one of KINDS ("simulate", "validate", "inverse", "capacity").
        duration: s, in place of the scenario's (the commands' --duration), or None.
        options: the kind's own as (key, value) pairs (capacity: lp, optimise; inverse: methods, replay,
            bound_force, bound_moment; others: none).
        columns: the patterns of the summary entries kept in a row (:func:`matcher`: `*` matches any text).
    """

    kind: str
    duration: float | None
    options: tuple
    columns: tuple[str, ...]

    def option(self, key: str, default=None):
        """The value of one of the study's options.

        Args:
            key: the option's name (e.g. "lp", "methods", "bound_force").
            default: returned when the study has no such option.

        Returns:
            Any: the option's value, or `default`.
        """
        return dict(self.options).get(key, default)


@dataclass(frozen=True)
class Axis:
    """One varied field of a sweep.

    Attributes:
        name: its column in the rows (default: the path).
        path: the scenario field varied (a `coopsim.io.overrides` path, e.g. inverse.payload.position[0]).
        values: the values of a grid design, in the field's own units, or None.
        bounds: (low, high) of a quasi-random design (sobol, halton), in the field's own units, or None.
    """

    name: str
    path: str
    values: tuple[float, ...] | None = None
    bounds: tuple[float, float] | None = None


@dataclass(frozen=True, eq=False)
class Sweep:
    """A validated sweep: the base scenario, the overrides of each point and the study run there.

    Attributes:
        name: the sweep's name (outputs go to out/NAME; default: the file's stem).
        description: the file's description, or "".
        file: the sweep file's path.
        scenario: the base scenario's path: the file's `scenario` joined to the sweep file's folder.
        base: the base scenario's data, as read from its YAML file.
        fixed: the (path, value) overrides of every point: the file's `set`, then the command line's.
        axes: the varied fields, in the file's order.
        design: "grid", "sobol" or "halton".
        points: (P, len(axes)) float, each point's axis values.
        study: what runs at each point.
        plot: the column patterns drawn.
        digest: SHA-256 (hex) of everything a row depends on: a checkpoint of another sweep is never
            resumed.
    """

    name: str
    description: str
    file: str
    scenario: str
    base: Any
    fixed: tuple
    axes: tuple[Axis, ...]
    design: str
    points: np.ndarray
    study: Study
    plot: tuple[str, ...]
    digest: str

    def overrides(self, index: int) -> list[tuple[str, Any]]:
        """The overrides of one point: the fixed ones, then one per axis.

        Args:
            index: the point, 0-based.

        Returns:
            list: (path, value) pairs, in the order they are applied.
        """
        return list(self.fixed) + [(a.path, float(v)) for a, v in zip(self.axes, self.points[index])]

    def model(self, index: int):
        """The validated model of one point: the base scenario with the point's overrides.

        Args:
            index: the point, 0-based.

        Returns:
            Model: the point's frozen Model (duration the study's when it sets one).

        Raises:
            ScenarioError: the overridden scenario is invalid (one line).
            OverrideError: an override does not apply (one line).
        """
        path = Path(self.scenario)
        data = apply_overrides(self.base, self.overrides(index), where=f"{path}: point {index}: --set")
        return model_from_dict(data, where=str(path), base_dir=path.parent, default_name=path.stem,
                               duration=self.study.duration)


# ------------------------------------------------------------------------------------------------
# the sweep file
# ------------------------------------------------------------------------------------------------

def load_sweep(path: str | Path, overrides=()) -> Sweep:
    """Read and validate a sweep file (format: module docstring).

    The base scenario with the fixed overrides, and every axis path, are checked here (each point's own
    values are checked when it runs).

    Args:
        path: the sweep file (YAML).
        overrides: (path, value) pairs set in the base scenario after the file's `set` (the command line's
            --set).

    Returns:
        Sweep: the validated sweep, its points laid out and its digest set.

    Raises:
        ScenarioError: one line "FILE: FIELD: reason", as for a scenario (a missing file included).
    """
    path = Path(path)
    if not path.is_file():
        raise ScenarioError(f"{path}: sweep file not found")
    root = Section(load_yaml(path), "", str(path))
    name = root.string("name", default=path.stem)
    description = root.string("description", default="")
    scenario = path.parent / root.string("scenario")
    if not scenario.is_file():
        root.fail("scenario", f"scenario file not found: {scenario}")
    fixed = _fixed(root) + list(overrides)
    design = root.string("design", choices=DESIGNS, default="grid")
    axes = _axes(root, design)
    points = _design_points(root, design, axes)
    study = _study(root.section("study"))
    plot = tuple(_patterns(root, "plot", PLOTS[study.kind]))
    root.done()
    base = load_yaml(scenario)
    sweep = Sweep(name, description, str(path), str(scenario), base, tuple(fixed), axes, design, points, study, plot,
                  "")
    _check_base(sweep, root)
    digest = hashlib.sha256(json.dumps(
        {"base": base, "fixed": sweep.fixed, "axes": [a.path for a in axes], "points": points.tolist(),
         "study": [study.kind, study.duration, list(study.options), list(study.columns)]},
        sort_keys=True, default=str).encode()).hexdigest()
    return replace(sweep, digest=digest)


def _fixed(root: Section) -> list[tuple[str, Any]]:
    sec = root.section("set", default=None)
    if sec is None:
        return []
    for key in sec.data:
        try:
            parse_path(str(key), where=f"{root.where}: set:")
        except CoopsimError as exc:
            raise ScenarioError(str(exc)) from None
        sec.raw(key)
    return [(str(k), v) for k, v in sec.data.items()]


def _axes(root: Section, design: str) -> tuple[Axis, ...]:
    axes = []
    for sec in root.items("axes", min_len=1):
        p = sec.string("path")
        try:
            parse_path(p, where=f"{sec.where}: {sec.field('path')}:")
        except CoopsimError as exc:
            raise ScenarioError(str(exc)) from None
        name = sec.string("name", default=p)
        if design == "grid":
            if sec.has("values") == sec.has("linspace"):
                sec.fail("values", "give either values (a list of numbers) or linspace [start, stop, count]")
            if sec.has("values"):
                values = sec.array("values", (None,))
                if len(values) == 0:
                    sec.fail("values", "expected at least one value")
            else:
                lin = sec.array("linspace", (3,))
                if not (lin[2].is_integer() and lin[2] >= 1):
                    sec.fail("linspace",
                             f"the count (third entry) must be a whole number of at least 1, got {lin[2]:g}")
                values = np.linspace(lin[0], lin[1], int(lin[2]))
            axes.append(Axis(name, p, values=tuple(float(v) for v in values)))
        else:
            lo, hi = sec.array("range", (2,))
            if not lo < hi:
                sec.fail("range", f"expected [low, high] with low < high, got {[lo, hi]}")
            axes.append(Axis(name, p, bounds=(float(lo), float(hi))))
        sec.done()
    names = [a.name for a in axes]
    if len(set(names)) != len(names):
        root.fail("axes", f"axis names must be unique, got {names}")
    return tuple(axes)


def _design_points(root: Section, design: str, axes: tuple[Axis, ...]) -> np.ndarray:
    """(P, len(axes)) values: the grid's combinations (the first axis slowest), or `samples` points of a
    scrambled Sobol or Halton sequence (scipy.stats.qmc, seeded) scaled to the axes' ranges."""
    if design == "grid":
        for key in ("samples", "seed"):
            if root.has(key):
                root.fail(key, "only for a sobol or halton design (a grid takes every combination of the values)")
        count = int(np.prod([len(a.values) for a in axes], dtype=float))
        if count > MAX_POINTS:
            root.fail("axes", f"{count:,} grid points, more than the {MAX_POINTS:,} a sweep may hold")
        return np.array(list(itertools.product(*(a.values for a in axes))), dtype=float).reshape(-1, len(axes))
    from scipy.stats import qmc

    n = root.whole("samples", positive=True, maximum=MAX_POINTS)
    seed = root.whole("seed", nonneg=True)
    kind = qmc.Sobol if design == "sobol" else qmc.Halton
    try:
        engine = kind(len(axes), scramble=True, rng=seed)
    except TypeError:                       # scipy < 1.15 names it seed
        engine = kind(len(axes), scramble=True, seed=seed)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")     # Sobol's balance note for a count that is not a power of 2
        unit = engine.random(n)
    lo, hi = np.array([a.bounds for a in axes]).T
    return qmc.scale(unit, lo, hi)


def _study(sec: Section) -> Study:
    kind = sec.string("kind", choices=KINDS)
    duration = sec.number("duration", default=None, positive=True)
    options: dict[str, Any] = {}
    if kind == "capacity":
        for key, default in (("lp", True), ("optimise", True)):
            v = sec.raw(key, default)
            if not isinstance(v, bool):
                sec.fail(key, f"expected true or false, got {v!r}")
            options[key] = v
    if kind == "inverse":
        methods = sec.raw("methods", list(METHODS))
        if not isinstance(methods, list) or not methods or any(m not in METHODS for m in methods):
            sec.fail("methods", f"expected a list of resolutions among {', '.join(METHODS)}, got {methods!r}")
        options["methods"] = tuple(methods)
        replay = sec.raw("replay", False)
        if not isinstance(replay, bool):
            sec.fail("replay", f"expected true or false, got {replay!r}")
        options["replay"] = replay
        options["bound_force"] = sec.number("bound_force", default=None, positive=True)
        options["bound_moment"] = sec.number("bound_moment", default=None, positive=True)
    columns = tuple(_patterns(sec, "columns", COLUMNS[kind]))
    sec.done()
    return Study(kind, duration, tuple(options.items()), columns)


def _patterns(sec: Section, key: str, default) -> list[str]:
    v = sec.raw(key, list(default))
    if not isinstance(v, list) or any(not isinstance(x, str) for x in v):
        sec.fail(key, f"expected a list of column names or patterns (* matches any text), got {v!r}")
    return v


def _check_base(sweep: Sweep, root: Section) -> None:
    """The base scenario with the fixed overrides and each axis's first value must make a model (each
    point's own values are checked when it runs: a bad one is that row's error)."""
    try:
        apply_overrides(sweep.base, sweep.fixed, where=f"{sweep.scenario}: set:")
        for k, a in enumerate(sweep.axes):
            apply_overrides(sweep.base, [(a.path, 0.0)], where=f"{root.where}: axes[{k}].path: --set")
        model = sweep.model(0)
    except CoopsimError as exc:
        raise ScenarioError(str(exc)) from None
    if sweep.study.kind == "capacity":
        require_motor_limits(model, sweep.scenario)


# ------------------------------------------------------------------------------------------------
# one point
# ------------------------------------------------------------------------------------------------

def study_summary(model, study: Study) -> dict:
    """The JSON summary of the single-run command of `study` on `model` (library calls only, no files).

    `simulation_summary` (simulate), the comparison of `cross_validate` (validate), `inverse_summary` of
    the study without its trade-off curve (inverse), `capacity_summary` (capacity).

    Args:
        model: the point's Model.
        study: what to run.

    Returns:
        dict: the nested summary the command prints with --json.

    Raises:
        ScenarioError: a capacity study on a model without motor limits; besides, whatever the run itself
            raises.
    """
    if study.kind == "simulate":
        return simulation_summary(simulate(closed_loop(model), duration=study.duration))
    if study.kind == "validate":
        return cross_validate(model, duration=study.duration).comparison.as_dict()
    if study.kind == "inverse":
        s = solve_study(model, study.option("methods"), duration=study.duration,
                        bounds=(study.option("bound_force"), study.option("bound_moment")))
        return inverse_summary(add_checks(s, study.option("replay"), curve=False))
    require_motor_limits(model, model.name)
    return capacity_summary(capacity_study(model, duration=study.duration, with_lp=study.option("lp"),
                                           optimise=study.option("optimise")))


def flatten(obj: Any, prefix: str = "") -> dict[str, Any]:
    """A nested summary as {dotted name: leaf}.

    Mapping keys are joined by '.', spaces made '_', list items named [i]; a list of mappings (the
    warnings, failed samples), or an empty list, becomes its length; NumPy scalars become Python ones.

    Args:
        obj: the summary (dicts, lists and tuples of leaves).
        prefix: the name of `obj` itself ("" at the top).

    Returns:
        dict: dotted name → leaf value, in the summary's order.
    """
    if isinstance(obj, dict):
        out: dict[str, Any] = {}
        for k, v in obj.items():
            out |= flatten(v, f"{prefix}.{k}".replace(" ", "_") if prefix else str(k).replace(" ", "_"))
        return out
    if isinstance(obj, (list, tuple)):
        if not obj or any(isinstance(v, dict) for v in obj):
            return {prefix: len(obj)}
        out = {}
        for i, v in enumerate(obj):
            out |= flatten(v, f"{prefix}[{i}]")
        return out
    if isinstance(obj, np.generic):
        obj = obj.item()
    return {prefix: obj}


def matcher(patterns):
    """A test of names against `patterns`: `*` stands for any text, every other character for itself.

    Brackets too match themselves (`min_manipulability[*]`); a name must match a whole pattern.

    Args:
        patterns: the patterns (an empty list matches nothing).

    Returns:
        Callable: name → bool, whether the name matches one of `patterns`.
    """
    regex = re.compile("(?:" + "|".join(re.escape(p).replace(r"\*", ".*") for p in patterns) + r")\Z" if patterns
                       else r"(?!)")
    return lambda name: regex.match(name) is not None


def select(flat: dict[str, Any], patterns) -> dict[str, Any]:
    """The entries of `flat` whose names match one of `patterns` (:func:`matcher`), in order.

    Args:
        flat: a flattened summary (:func:`flatten`).
        patterns: the name patterns kept.

    Returns:
        dict: the matching entries.
    """
    match = matcher(patterns)
    return {k: v for k, v in flat.items() if match(k)}


def study_row(summary: dict, study: Study) -> dict[str, Any]:
    """The study's columns of a single-run summary (what :func:`evaluate_point` puts in a row).

    Args:
        summary: the nested summary (:func:`study_summary`).
        study: the study (its `columns` patterns).

    Returns:
        dict: dotted name → value of the kept entries.
    """
    return select(flatten(summary), study.columns)


def error_text(exc: BaseException) -> str:
    """An exception as a row's one-line error: a coopsim error's own text, anything else prefixed by its
    type (`coopsim.core.errors.one_line`).

    Args:
        exc: the exception.

    Returns:
        str: its message as one line.
    """
    text = one_line(exc)
    return text if isinstance(exc, CoopsimError) else f"{type(exc).__name__}: {text}"


def evaluate_point(sweep: Sweep, index: int) -> dict[str, Any]:
    """The row of one point: point, the axis values, error, then the study's columns.

    error is None, or the one-line reason the point failed (bad values, a failed run); a failed point has
    no study columns. Deterministic; runs anywhere the scenario's files are (a Dask worker). Never raises
    for the point's own failure.

    Args:
        sweep: the sweep.
        index: the point, 0-based.

    Returns:
        dict: column name → value: "point" (int), one float per axis (its name), "error", the study's
            columns.
    """
    row: dict[str, Any] = {"point": int(index)}
    row |= {a.name: float(v) for a, v in zip(sweep.axes, sweep.points[index])}
    try:
        metrics = study_row(study_summary(sweep.model(index), sweep.study), sweep.study)
        row["error"] = None
    except Exception as exc:            # noqa: BLE001 — a failing point is a row, the sweep goes on
        metrics = {}
        row["error"] = error_text(exc)
    return row | metrics
