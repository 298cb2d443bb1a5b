"""Helpers the tests share (not fixtures): the repository's paths, the real CLI in this process or a
fresh one, the processes of a process group (from /proc), scenario data mutated at a path, random and
consistent states, a relative error, MuJoCo's own open-chain quantities and its KKT acceleration as an
independent reference, and the check of the compiled stage terms against the reference ones.
"""

from __future__ import annotations

import contextlib
import copy
import io
import os
import signal
import subprocess
import sys
import textwrap
import time
import warnings
from pathlib import Path

import mujoco
import numpy as np

from coopsim.twin.mjcf import build_spec, dof_address, qpos_address, static_settings

ROOT = Path(__file__).resolve().parents[1]   # the repository (this file is tests/helpers.py)
SCENARIOS = ROOT / "scenarios"


def _show_on_stderr(message, category, filename, lineno, file=None, line=None):
    sys.stderr.write(warnings.formatwarning(message, category, filename, lineno, line))


def run_cli(*args, cwd, process: bool = False):
    """The real `coopsim` command in folder `cwd`, its output captured; returns a CompletedProcess.
    By default its entry point `coopsim.cli.main` runs in this process (the compiled kernels are loaded
    once per test worker, not once per command; an argparse exit is its exit status); process=True runs
    `python -m coopsim.cli` in a fresh process, for what only a new process shows (e.g. that a log does
    not depend on the process's hash seed)."""
    argv = [str(a) for a in args]
    if process:
        return subprocess.run([sys.executable, "-m", "coopsim.cli", *argv], cwd=cwd, capture_output=True, text=True,
                              timeout=600)
    from coopsim.cli import main

    out, err = io.StringIO(), io.StringIO()
    with contextlib.chdir(cwd), contextlib.redirect_stdout(out), contextlib.redirect_stderr(err), \
            warnings.catch_warnings():
        warnings.showwarning = _show_on_stderr     # as Python shows them (pytest would record them instead)
        try:
            code = main(argv)
        except SystemExit as exc:
            code = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 2)
    return subprocess.CompletedProcess(["coopsim", *argv], code, out.getvalue(), err.getvalue())


def running_processes(group: int) -> dict[int, int]:
    """The processes of process group `group` that have not ended (a zombie has), from /proc: pid → its
    parent's pid."""
    found = {}
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                fields = (entry / "stat").read_text().rsplit(")", 1)[1].split()   # after "pid (name)"
            except OSError:                  # ended meanwhile
                continue
            if int(fields[2]) == group and fields[0] != "Z":
                found[int(entry.name)] = int(fields[1])
    return found


def survivors(group: int, within_s: float = 5.0) -> dict[int, int]:
    """The processes of group `group` still running `within_s` seconds from now (none: returns as soon as
    there are none); each one found is then killed, so that a failing test leaves none behind."""
    deadline = time.monotonic() + within_s
    while (left := running_processes(group)) and time.monotonic() < deadline:
        time.sleep(0.05)
    for pid in left:
        with contextlib.suppress(ProcessLookupError):
            os.kill(pid, signal.SIGKILL)
    return left


def mutated(base: dict, path: list, value) -> dict:
    """A deep copy of scenario data with `value` put at `path` (a list of keys; value None deletes)."""
    data = copy.deepcopy(base)
    node = data
    for key in path[:-1]:
        node = node[key]
    if value is None:
        del node[path[-1]]
    else:
        node[path[-1]] = value
    return data


def paper_residual_by_hand() -> np.ndarray:
    """The paper scenario's loop-closure residual [Δx, Δy, Δψ] (m, m, rad) at its rounded initial
    angles, by planar trigonometry from the YAML's numbers (no coopsim code): each arm's end-effector
    point Σ lᵢ (cos, sin)(θ₁+…+θᵢ) from its base; the bar's centre 0.2 m along arm 1's last link past
    its end-effector (grasp at x = −0.2 in the bar frame, no rotation); arm 2's grasp 0.2 m further
    along the bar, its end-effector turned 180° from the bar (grasp yaw 180°)."""
    import yaml

    data = yaml.safe_load((SCENARIOS / "paper_planar_2x3.yaml").read_text())
    ends = []
    for arm in data["arms"]:
        x, y = arm["base"]["position"][:2]
        heading = 0.0
        for deg, link in zip(arm["initial"]["angles_deg"], arm["links"]):
            heading += np.deg2rad(deg)
            x, y = x + link["box"]["length"] * np.cos(heading), y + link["box"]["length"] * np.sin(heading)
        ends.append((np.array([x, y]), heading))
    (p1, h1), (p2, h2) = ends
    g1, g2 = (np.array(g["position"][:2]) for g in data["object"]["grasps"])
    along = np.array([np.cos(h1), np.sin(h1)])            # the bar's x axis = arm 1's end-effector x axis
    grasp2 = p1 + (g2[0] - g1[0]) * along                 # arm 2's grasp point on the bar
    dpsi = (h2 - (h1 + np.pi) + np.pi) % (2 * np.pi) - np.pi
    return np.array([*(p2 - grasp2), dpsi])


class MujocoReference:
    """MuJoCo's own open-chain quantities for a coopsim model (arms, and the object on its carrier
    when with_object=True; no welds), in coopsim's stacked joint order."""

    def __init__(self, model, with_object: bool):
        spec = build_spec(model, static_settings(model), with_object=with_object)
        for eq in list(spec.equalities):
            spec.delete(eq)
        self.m = spec.compile()
        self.d = mujoco.MjData(self.m)
        self.qadr = qpos_address(self.m, model)
        self.dadr = dof_address(self.m, model)

    def set_state(self, q, qd):
        self.d.qpos[self.qadr] = q
        self.d.qvel[self.dadr] = qd
        mujoco.mj_forward(self.m, self.d)

    def mass_matrix(self):
        M = np.zeros((self.m.nv, self.m.nv))
        mujoco.mj_fullM(self.m, self.d, M)
        return M[np.ix_(self.dadr, self.dadr)]

    def bias(self):
        return self.d.qfrc_bias[self.dadr].copy()

    def site_jacobian(self, name):
        """(J (6, n) of the site's point [v; ω], J̇q̇ (6,)) in coopsim's joint order."""
        J, Jd = self.site_jacobian_and_rate(name)
        return J, Jd @ self.d.qvel[self.dadr]

    def site_jacobian_and_rate(self, name):
        """(J, J̇) (6, n) each, of the site's point [v; ω] (mj_jac, mj_jacDot), in coopsim's joint order."""
        sid = self.m.site(name).id
        body = self.m.site_bodyid[sid]
        point = self.d.site_xpos[sid].copy()
        jp, jr = np.zeros((3, self.m.nv)), np.zeros((3, self.m.nv))
        mujoco.mj_jac(self.m, self.d, jp, jr, point, body)
        dp, dr = np.zeros((3, self.m.nv)), np.zeros((3, self.m.nv))
        mujoco.mj_jacDot(self.m, self.d, dp, dr, point, body)
        return np.vstack([jp, jr])[:, self.dadr], np.vstack([dp, dr])[:, self.dadr]


def random_states(model, count: int, seed: int):
    """`count` random (q, qd): angles uniform in [−π, π], rates standard normal (rad/s)."""
    rng = np.random.default_rng(seed)
    n = model.n_total
    return [(rng.uniform(-np.pi, np.pi, n), rng.normal(size=n)) for _ in range(count)]


def rel_err(a, b) -> float:
    """max |a − b| / max(1, max |b|): relative for large values, absolute near zero."""
    a, b = np.asarray(a), np.asarray(b)
    return float(np.max(np.abs(a - b)) / max(1.0, np.max(np.abs(b))))


def consistent_states(model, count: int, seed: int, spread: float = 0.4):
    """`count` random states on the loop-closure manifold: q0 + N(0, spread²) and N(0, 1) rates,
    projected with coopsim's Gauss–Newton projection (draws that do not converge are skipped)."""
    from coopsim.core.errors import ConstraintError
    from coopsim.dynamics.manifold import project_positions, project_velocities

    rng = np.random.default_rng(seed)
    states = []
    for _ in range(20 * count):
        try:
            q, _ = project_positions(model, model.q0 + rng.normal(scale=spread, size=model.n_total), 1e-13)
        except ConstraintError:
            continue
        states.append((q, project_velocities(model, q, rng.normal(size=model.n_total))))
        if len(states) == count:
            return states
    raise RuntimeError("could not draw enough consistent states")


def mujoco_kkt_acceleration(model, ref: "MujocoReference", q, qd, tau):
    """θ̈ from the KKT system built from MuJoCo's open chain (object attached to its carrier):
    [M Gᵀ; G 0][θ̈; λ] = [τ − bias; −Ġθ̇], G = S (J_EE,m − J_grasp,m) for every arm m but the carrier."""
    ref.set_state(q, qd)
    M, bias = ref.mass_matrix(), ref.bias()
    G, gamma = [], []
    for m in range(model.r):
        if m == model.object.carrier:
            continue
        J_ee, a_ee = ref.site_jacobian(f"a{m}_ee")
        J_g, a_g = ref.site_jacobian(f"grasp{m}")
        G.append(model.rows @ (J_ee - J_g))
        gamma.append(model.rows @ (a_ee - a_g))
    G, gamma = np.vstack(G), np.concatenate(gamma)
    n, k = M.shape[0], G.shape[0]
    K = np.block([[M, G.T], [G, np.zeros((k, k))]])
    sol = np.linalg.solve(K, np.concatenate([tau - bias, -gamma]))
    return sol[:n]


# stage terms of the two engines, relative (max |a − b| / max(1, max |b|)): each a direct computation
TERMS_RTOL = 1e-12


def constraint_condition(T) -> float:
    """cond(Λ M⁻¹ Λᵀ), the condition number of the closed chain's constraint system (eqs. 22–25) for
    the reference `chain_terms` T."""
    return float(np.linalg.cond(T.Lam @ np.linalg.solve(T.M, T.Lam.T)))


def assert_compiled_terms_match_the_reference(scene, count: int):
    """Every stage term of both engines at `count` random consistent states ≤ TERMS_RTOL relative, and θ̈ ≤
    TERMS_RTOL + eps·cond(Λ M⁻¹ Λᵀ): a backward-stable solve's forward error is of order eps·cond (measured
    below 1e-17·cond on the bundled scenes, CPU-specific or generic code alike, a margin of 20)."""
    rng = np.random.default_rng(11)
    worst = {}
    eps = np.finfo(float).eps
    from coopsim.compiled import api
    from coopsim.dynamics.closed_chain import chain_terms, forward_dynamics

    for q, qd in consistent_states(scene, count, seed=12):
        tau = rng.normal(scale=2.0, size=scene.n_total)
        T = chain_terms(scene, q, qd)
        acc = forward_dynamics(scene, T, tau)
        ev = api.forward(scene, q, qd, tau)
        W = api.compiled(scene).W
        pairs = {"h": (W.h, T.h), "Lam": (W.Lam, T.Lam),
                 "Lam_dot_qd": (W.Lam_dot_qd, T.Lam_dot_qd), "J_o": (W.J_o[:, :T.J_o.shape[1]], T.J_o),
                 "v_o": (W.v_o, T.v_o), "p_C": (W.p_C, T.obj.p_C), "R_o": (W.R_o, T.obj.R_o)}
        for m, sl in enumerate(scene.dof_slices):
            n = sl.stop - sl.start
            pairs[f"M[{m}]"] = (W.Mb[sl, :n], T.M[sl, sl])
            pairs[f"J[{m}]"] = (W.J[m, :, :n], T.J[m])
            pairs[f"Jd_qd[{m}]"] = (W.Jd_qd[m], T.Jd_qd[m])
        for name, (a, b) in pairs.items():
            worst[name] = max(worst.get(name, 0.0), rel_err(a, b))
        bound = TERMS_RTOL + eps * constraint_condition(T)
        qdd = worst.get("qdd", (0.0, bound))
        if rel_err(ev.qdd, acc.qdd) / bound > qdd[0] / qdd[1]:
            worst["qdd"] = (rel_err(ev.qdd, acc.qdd), bound)
        assert ev.status == 0
    bad = {k: v for k, v in worst.items() if (v[0] > v[1] if k == "qdd" else v > TERMS_RTOL)}
    assert not bad, f"compiled terms differ from the reference (qdd: (error, bound)): {bad}"


# a module compiled with coopsim's decorators: a kernel (axpy) and two entries calling it (tests/compiled)
LINKING_MODULE = textwrap.dedent('''
    import numpy as np
    from coopsim.compiled.toolchain.jit import entry, kernel


    @kernel
    def axpy(a, x, y):
        """y ← a x + y; returns the sum of y."""
        s = 0.0
        for i in range(x.shape[0]):
            y[i] += a * x[i]
            s += y[i]
        return s


    @entry
    def first(a, x, y):
        return axpy(a, x, y)


    @entry
    def second(a, x, y):
        return 2.0 * axpy(a, x, y)
''')
