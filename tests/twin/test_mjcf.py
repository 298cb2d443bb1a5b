"""The MuJoCo twin: only what the scene needs, the same parameters as the native model, files up to
date; each file in models/ opens at the consistent initial state, runs the twin of `coopsim run` bit for
bit from its keyframe, and agrees with the native model within the scenario's thresholds.

The files in models/ were written on one machine; the numbers in them (link frames, inertias, the
keyframe's projected angles) come out of floating-point computations whose last bits depend on the CPU
and the libraries' SIMD paths. So a committed file is compared with the file regenerated here by value
(`xml_differences`: the same elements and attributes, every number within FILE_RTOL), and the claims
that hold to the last bit (the writer keeps every digit, a file's keyframe run is `coopsim run`'s twin)
are checked on the file regenerated in this process."""

from __future__ import annotations

import xml.etree.ElementTree as ET
from typing import NamedTuple

import mujoco
import numpy as np
import pytest

from coopsim.twin.compare import orientation_error
from coopsim.twin.mjcf import KEYFRAME, build_spec, dof_address, launch_viewer, mjcf_text, qpos_address
from coopsim.twin.weld import resolved
from coopsim.core.model import Model, TorqueFunction, torque_at
from coopsim.twin.mujoco_run import run_twin
from coopsim.io.scenario import load_scenario
from coopsim.forward.simulate import initial_state, simulate
from coopsim.core.results import output_times
from helpers import ROOT, SCENARIOS

SCENARIO_FILES = sorted(SCENARIOS.glob("*.yaml"))
IDS = [p.stem for p in SCENARIO_FILES]

# A number in a committed file against the same number recomputed on this machine: relative to the
# largest magnitude in its attribute (a vector's entries share its rounding scale, so a component that
# is zero to rounding, e.g. of a quaternion, is compared against the vector's size). Each number is a
# short chain of trigonometry and products from the scenario (a few ulp apart between machines), or a
# keyframe angle from the converged loop-closure projection (a few ulp times the constraint Jacobian's
# conditioning, below 1e3 on the bundled scenes); 1e-13 is ~450 ulp.
FILE_RTOL = 1e-13
# A compiled model field of the committed file against the spec's, normwise relative: MuJoCo derives
# some of them (body_invweight0, dof_invweight0, stat.meaninertia) from the mass matrix at qpos0, one
# more factorization on top of the file's numbers.
COMPILED_RTOL = 1e-12


def _numbers(value: str) -> list[float] | None:
    """The attribute's whitespace-separated tokens as floats, or None if any is not a number."""
    try:
        return [float(tok) for tok in value.split()]
    except ValueError:
        return None


def _element_name(el: ET.Element) -> str:
    return f"{el.tag}[{el.get('name')}]" if el.get("name") else el.tag


def xml_differences(committed: str, regenerated: str, rtol: float = FILE_RTOL) -> list[str]:
    """Where two MJCF texts differ beyond rounding: a line per element whose tag, attribute names,
    non-numeric values, comment text or children differ, and per attribute whose numbers differ by more
    than rtol relative to the attribute's largest magnitude (with the element's path and the size of
    the difference). Empty when the texts are the same file up to rounding."""
    def parse(text):
        return ET.fromstring(text, parser=ET.XMLParser(target=ET.TreeBuilder(insert_comments=True)))

    out: list[str] = []

    def walk(a: ET.Element, b: ET.Element, path: str) -> None:
        here = f"{path}/{_element_name(a)}"
        if a.tag != b.tag:
            out.append(f"{path}: element {_element_name(a)} committed, {_element_name(b)} regenerated")
            return
        if a.tag is ET.Comment:
            if a.text != b.text:
                out.append(f"{path}: comment text differs")
            return
        if set(a.attrib) != set(b.attrib):
            out.append(f"{here}: attributes {sorted(a.attrib)} committed, {sorted(b.attrib)} regenerated")
        for key in sorted(set(a.attrib) & set(b.attrib)):
            va, vb = a.attrib[key], b.attrib[key]
            na, nb = _numbers(va), _numbers(vb)
            if na is None or nb is None or len(na) != len(nb):
                if va != vb:
                    out.append(f"{here} {key}: {va!r} committed, {vb!r} regenerated")
                continue
            na, nb = np.array(na), np.array(nb)
            scale = max(np.max(np.abs(na), initial=0.0), np.max(np.abs(nb), initial=0.0))
            gap = np.max(np.abs(na - nb), initial=0.0)
            if gap > rtol * scale:
                out.append(f"{here} {key}: {va!r} committed, {vb!r} regenerated "
                           f"(differs by {gap:.3g}, {gap / scale:.3g} relative > {rtol:g})")
        ca, cb = list(a), list(b)
        if len(ca) != len(cb):
            out.append(f"{here}: {len(ca)} children committed, {len(cb)} regenerated")
        for x, y in zip(ca, cb):
            walk(x, y, here)

    walk(parse(committed), parse(regenerated), "")
    return out


class Twin(NamedTuple):
    """One bundled scenario's twin files: the scenario's model, the MJCF text regenerated here, that
    text compiled, the committed file in models/ (text and compiled), and the spec `coopsim run`
    compiles."""
    model: Model
    text: str
    file: mujoco.MjModel
    committed_text: str
    committed: mujoco.MjModel
    exact: mujoco.MjModel


def _twin(path) -> Twin:
    model = resolved(load_scenario(path))      # the step `coopsim mjcf` and `coopsim run` take
    text = mjcf_text(model, f"scenarios/{path.name}")
    committed = ROOT / "models" / f"{path.stem}.xml"
    assert committed.is_file(), f"{committed} missing: run `coopsim mjcf`"
    return Twin(model, text, mujoco.MjModel.from_xml_string(text), committed.read_text(),
                mujoco.MjModel.from_xml_path(str(committed)), build_spec(model).compile())


@pytest.fixture(scope="module")
def twin_files():
    """Per scenario stem: its `Twin`."""
    return {p.stem: _twin(p) for p in SCENARIO_FILES}


def _header(text: str) -> str:
    return text[:text.index("<mujoco")]


@pytest.mark.parametrize("name", IDS)
def test_model_file_is_up_to_date(name, twin_files):
    """The committed file is the one `coopsim mjcf` writes from the scenario, up to rounding: the same
    header, elements and attributes, every number within FILE_RTOL of the recomputed one."""
    twin = twin_files[name]
    assert _header(twin.committed_text) == _header(twin.text), f"{name}: header differs: run `coopsim mjcf`"
    diffs = xml_differences(twin.committed_text, twin.text)
    assert not diffs, f"models/{name}.xml is out of date with scenarios/{name}.yaml (run `coopsim mjcf`):\n" + \
        "\n".join(diffs[:20])


def test_xml_differences_names_the_attribute_and_the_gap():
    """The comparison itself: rounding passes, a changed number, attribute or element is reported."""
    a = '<mujoco><body name="b" pos="1 0 0.31992421761028955"/></mujoco>'
    assert xml_differences(a, a.replace("0.31992421761028955", "0.3199242176102895")) == []
    assert xml_differences(a, a.replace("1 0 ", "1 1e-15 ")) == []
    diff = xml_differences(a, a.replace("0.31992421761028955", "0.3199242176"))
    assert len(diff) == 1 and diff[0].startswith("/mujoco/body[b] pos:") and "relative" in diff[0], diff
    assert xml_differences(a, a.replace('name="b"', 'name="c"')) == \
        ["/mujoco/body[b] name: 'b' committed, 'c' regenerated"]
    assert "attributes" in xml_differences(a, a.replace("/>", ' quat="1 0 0 0"/>'))[0]
    assert "children" in xml_differences(a, a.replace("/>", "><geom/></body>"))[0]


@pytest.mark.parametrize("name", ["paper_planar_2x3", "spatial_6r_pair"])
def test_mjcf_text_is_deterministic(name):
    """`coopsim mjcf` writes the same bytes for the same scenario (two loads, two writes, one machine)."""
    path = SCENARIOS / f"{name}.yaml"
    assert mjcf_text(load_scenario(path), "s.yaml") == mjcf_text(load_scenario(path), "s.yaml")


@pytest.mark.parametrize("scenario", ["paper", "spatial"])
def test_twin_holds_only_what_the_scene_needs(scenario, request):
    model = request.getfixturevalue(scenario)
    m = build_spec(model).compile()
    n = model.n_total
    assert m.nbody == 1 + n + 1, "world + one body per link + the object"
    assert m.njnt == n and np.all(m.jnt_type == mujoco.mjtJoint.mjJNT_HINGE)
    assert m.neq == model.r - 1 and np.all(m.eq_type == mujoco.mjtEq.mjEQ_WELD)
    assert m.nu == n and np.all(m.actuator_gear[:, 0] == 1.0)
    assert m.opt.disableflags & mujoco.mjtDisableBit.mjDSBL_CONTACT
    assert m.ngeom == n + 1 and np.all(m.geom_contype == 0) and np.all(m.geom_conaffinity == 0)


@pytest.mark.parametrize("scenario", ["paper", "spatial"])
def test_twin_parameters_equal_the_native_model(scenario, request):
    model = request.getfixturevalue(scenario)
    m = build_spec(model).compile()
    bodies = [m.body(f"a{a}_l{i}").id for a, arm in enumerate(model.arms) for i in range(arm.n)]
    bodies.append(m.body("object").id)
    masses = np.concatenate([a.link_mass for a in model.arms] + [[model.object.mass]])
    assert np.array_equal(m.body_mass[bodies], masses)
    inertias = [I for a in model.arms for I in a.link_inertia] + [model.object.inertia]
    for b, I in zip(bodies, inertias):
        assert np.allclose(np.sort(m.body_inertia[b]), np.linalg.eigvalsh(I), rtol=1e-13, atol=0)
    assert np.allclose(m.opt.gravity, model.gravity, rtol=0, atol=0)


@pytest.mark.parametrize("scenario", ["paper", "spatial"])
def test_welds_hold_at_the_consistent_initial_state(scenario, request):
    """The weld anchor and relative pose are set explicitly: zero violation where the loop closes."""
    model = request.getfixturevalue(scenario)
    m = build_spec(model).compile()
    d = mujoco.MjData(m)
    d.qpos[qpos_address(m, model)] = initial_state(model).q
    mujoco.mj_forward(m, d)
    assert d.nefc == 6 * (model.r - 1)
    assert np.max(np.abs(d.efc_pos[: d.nefc])) <= 1e-12


# Every compiled quantity the dynamics reads (qpos0 and the inverse weights computed there set the
# welds' regularisation, meaninertia the solver's scale).
PHYSICS_FIELDS = ["qpos0", "body_parentid", "body_pos", "body_quat", "body_ipos", "body_iquat", "body_mass",
                  "body_inertia", "body_invweight0", "dof_invweight0", "dof_armature", "dof_damping",
                  "dof_frictionloss", "jnt_type", "jnt_pos", "jnt_axis", "jnt_stiffness", "eq_type", "eq_obj1id",
                  "eq_obj2id", "eq_data", "eq_solref", "eq_solimp", "actuator_trnid", "actuator_gear",
                  "actuator_gainprm", "actuator_biasprm", "actuator_ctrllimited", "actuator_forcelimited"]
OPTION_FIELDS = ["timestep", "integrator", "gravity", "tolerance", "iterations", "solver", "disableflags",
                 "enableflags", "cone", "jacobian", "impratio"]


def _field_gap(a, b) -> float:
    """Normwise relative difference of two compiled-model arrays (0 for equal ones)."""
    a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
    scale = max(np.max(np.abs(a), initial=0.0), np.max(np.abs(b), initial=0.0))
    return float(np.max(np.abs(a - b), initial=0.0) / scale) if scale else 0.0


def _compiled_differences(m: mujoco.MjModel, exact: mujoco.MjModel, rtol: float) -> list[str]:
    """The sizes, PHYSICS_FIELDS, OPTION_FIELDS and stat.meaninertia of `m` that differ from `exact`'s
    by more than rtol (normwise relative; rtol=0: any difference)."""
    sizes = ("nq", "nv", "nbody", "njnt", "neq", "nu")
    if [getattr(m, s) for s in sizes] != [getattr(exact, s) for s in sizes]:
        return [f"sizes {[getattr(m, s) for s in sizes]} ≠ the spec's {[getattr(exact, s) for s in sizes]}"]
    pairs = [(f, getattr(m, f), getattr(exact, f)) for f in PHYSICS_FIELDS]
    pairs += [(f"opt.{f}", getattr(m.opt, f), getattr(exact.opt, f)) for f in OPTION_FIELDS]
    pairs.append(("stat.meaninertia", m.stat.meaninertia, exact.stat.meaninertia))
    return [f"{f} differs from the spec's by {_field_gap(a, b):.3g} relative" for f, a, b in pairs
            if (not np.array_equal(a, b) if rtol == 0 else _field_gap(a, b) > rtol)]


@pytest.mark.parametrize("name", IDS)
def test_model_file_compiles_to_the_twin_exactly(name, twin_files):
    """Saved as written: no number rounded (MuJoCo's writer of compiled values keeps 6 digits). The
    text written here compiles to the spec bit for bit; the committed file to within COMPILED_RTOL."""
    twin = twin_files[name]
    assert not _compiled_differences(twin.file, twin.exact, 0.0), (name, _compiled_differences(twin.file, twin.exact, 0.0))
    diffs = _compiled_differences(twin.committed, twin.exact, COMPILED_RTOL)
    assert not diffs, f"models/{name}.xml: {diffs}"


def _keyframe(m: mujoco.MjModel, model: Model):
    """(qpos, qvel, ctrl) of key 0 in coopsim's joint order, and the MjData reset to it."""
    assert m.nkey == 1 and m.key(0).name == KEYFRAME, f"one keyframe named {KEYFRAME!r}"
    d = mujoco.MjData(m)
    mujoco.mj_resetDataKeyframe(m, d, 0)
    ctrl = [m.actuator(f"a{a}_m{i}").id for a, arm in enumerate(model.arms) for i in range(arm.n)]
    return d.qpos[qpos_address(m, model)].copy(), d.qvel[dof_address(m, model)].copy(), d.ctrl[ctrl].copy(), d


@pytest.mark.parametrize("name", IDS)
def test_keyframe_is_the_consistent_initial_state(name, twin_files):
    """Key 0 is `initial`: the projected state `coopsim run` starts the twin from, τ(0) as ctrl; to the
    last bit in the text written here, within FILE_RTOL in the committed file."""
    twin = twin_files[name]
    model, init = twin.model, initial_state(twin.model)
    for which, m, rtol in (("written here", twin.file, 0.0), ("committed", twin.committed, FILE_RTOL)):
        q, qd, ctrl, d = _keyframe(m, model)
        assert d.time == 0.0, f"{name} ({which}): keyframe time {d.time} s"
        for what, got, ref in (("qpos", q, init.q), ("qvel", qd, init.qd),
                               ("ctrl", ctrl, torque_at(model.torques, 0.0))):
            gap = np.max(np.abs(got - ref), initial=0.0)
            assert gap <= rtol * max(1.0, np.max(np.abs(ref), initial=0.0)), \
                f"{name} ({which}): keyframe {what} off the consistent state by {gap:.3g}"
        mujoco.mj_forward(m, d)
        weld = np.max(np.abs(d.efc_pos[: d.nefc]))
        assert d.nefc == 6 * (model.r - 1) and weld <= 1e-12, f"{name}: weld violation at the keyframe {weld:.3g}"
        assert np.all(np.isfinite(d.qacc)) and np.max(np.abs(d.qacc)) < 1e2, \
            f"{name}: |qacc| at the keyframe {np.max(np.abs(d.qacc)):.3g} rad/s²"


def _step_file(m, model, t_out, torque):
    """Reset the file's model to its keyframe and step it with control callback `torque(t)`, sampled at
    t_out as run_twin samples (mj_forward after the steps): q, qd, qacc, object pose, weld violation."""
    d = mujoco.MjData(m)
    mujoco.mj_resetDataKeyframe(m, d, 0)
    qadr, dadr, obj = qpos_address(m, model), dof_address(m, model), m.body("object").id
    ctrl = np.array([m.actuator(f"a{a}_m{i}").id for a, arm in enumerate(model.arms) for i in range(arm.n)])
    steps = np.round(np.diff(t_out) / m.opt.timestep).astype(int)
    out = {k: [] for k in ("q", "qd", "qdd", "pos", "quat", "weld")}

    def control(_, data):
        data.ctrl[ctrl] = torque(data.time)

    mujoco.set_mjcb_control(control)
    try:
        for i in range(len(t_out)):
            for _ in range(steps[i - 1] if i else 0):
                mujoco.mj_step(m, d)
            mujoco.mj_forward(m, d)
            for k, v in (("q", d.qpos[qadr]), ("qd", d.qvel[dadr]), ("qdd", d.qacc[dadr]),
                         ("pos", d.xpos[obj]), ("quat", d.xquat[obj])):
                out[k].append(v.copy())
            out["weld"].append(np.max(np.abs(d.efc_pos[: d.nefc])))
    finally:
        mujoco.set_mjcb_control(None)
    return {k: np.array(v) for k, v in out.items()}


def _fast_torque(model):
    """τ(t) as one piecewise-linear table on the union of the arms' breakpoints (a few µs a call instead
    of torque_at's ~35; equal to it to rounding)."""
    if isinstance(model.torques, TorqueFunction):
        return lambda t: torque_at(model.torques, t)
    T = np.unique(np.concatenate([tab.times for tab in model.torques]))
    V = np.array([torque_at(model.torques, t) for t in T])
    if len(T) == 1:
        return lambda t: V[0]
    S = np.diff(V, axis=0) / np.diff(T)[:, None]

    def torque(t):
        if t <= T[0]:
            return V[0]
        if t >= T[-1]:
            return V[-1]
        j = np.searchsorted(T, t, side="right") - 1
        return V[j] + (t - T[j]) * S[j]
    return torque


@pytest.mark.parametrize("name", IDS)
def test_file_from_its_keyframe_is_the_twin_of_coopsim_run_bit_for_bit(name, twin_files):
    """The file (keyframe, light, floor, camera: visual additions) against the bare spec `coopsim run`
    steps from the consistent state: the same trajectory to the last bit over the first 0.05 s. The
    file is the one written in this process (the committed one's numbers are the same up to rounding,
    `test_model_file_is_up_to_date`, and its run is checked against the native model below)."""
    model, m = twin_files[name].model, twin_files[name].file
    t_out = output_times(0.05, model.integrator.output_dt)
    init = initial_state(model)
    twin = run_twin(model, init.q, init.qd, t_out)
    got = _step_file(m, model, t_out, lambda t: torque_at(model.torques, t))
    for key, ref in (("q", twin.q), ("qd", twin.qd), ("qdd", twin.qdd), ("pos", twin.object_pos),
                     ("quat", twin.object_quat), ("weld", twin.weld_violation)):
        assert np.array_equal(got[key], ref), \
            f"{name}: {key} from the file's keyframe differs from run_twin by {np.max(np.abs(got[key] - ref)):.3g}"


# The file's own run against the native model over (up to) this much of each scenario's duration.
AGREEMENT_WINDOW = 1.0


@pytest.mark.parametrize("name", IDS)
def test_file_from_its_keyframe_agrees_with_the_native_model(name, twin_files):
    """The saved XML alone, reset to its keyframe and stepped with the scenario's torques, stays finite
    and within the scenario's validation thresholds of the native run on the same output grid."""
    model, m = twin_files[name].model, twin_files[name].committed
    duration = min(model.duration, AGREEMENT_WINDOW)
    native = simulate(model, duration=duration)
    got = _step_file(m, model, native.t, _fast_torque(model))
    assert all(np.all(np.isfinite(v)) for v in got.values()), f"{name}: non-finite state from the file"
    th = model.validation
    for what, err, limit in (
            ("joint angle error (rad)", np.abs(got["q"] - native.q), th.max_angle_error),
            ("joint rate error (rad/s)", np.abs(got["qd"] - native.qd), th.max_rate_error),
            ("object position error (m)", np.linalg.norm(got["pos"] - native.object_pos, axis=1),
             th.max_object_position_error),
            ("object orientation error (rad)", orientation_error(got["quat"], native.object_quat),
             th.max_object_orientation_error),
            ("weld violation", got["weld"], th.max_weld_violation)):
        assert np.max(err) <= limit, f"{name}: max {what} {np.max(err):.3g} over {duration:g} s > {limit:g}"


@pytest.mark.parametrize("name", IDS)
def test_scene_is_visual_only_and_frames_the_scene(name, twin_files):
    """One directional light along gravity, a contact-free massless floor below everything with its
    normal against gravity, a fixed camera (and the free camera's statistic) that sees every link,
    base and the object at the keyframe."""
    model, m, exact = twin_files[name].model, twin_files[name].committed, twin_files[name].exact
    d = mujoco.MjData(m)
    mujoco.mj_resetDataKeyframe(m, d, 0)
    mujoco.mj_forward(m, d)
    up = -model.gravity / np.linalg.norm(model.gravity)
    assert m.nlight == 1 and m.light_type[0] == mujoco.mjtLightType.mjLIGHT_DIRECTIONAL, f"{name}: light"
    assert np.allclose(d.light_xdir[0], -up, atol=1e-12), f"{name}: light direction {d.light_xdir[0]}"
    floor = m.geom("floor").id
    assert m.geom_type[floor] == mujoco.mjtGeom.mjGEOM_PLANE and m.geom_bodyid[floor] == 0, f"{name}: floor"
    assert m.geom_contype[floor] == 0 and m.geom_conaffinity[floor] == 0, f"{name}: floor collides"
    assert m.ngeom == exact.ngeom + 1 and np.all(m.geom_contype == 0) and np.all(m.geom_conaffinity == 0)
    normal = d.geom_xmat[floor].reshape(3, 3)[:, 2]
    assert np.allclose(normal, up, atol=1e-12), f"{name}: floor normal {normal}, against gravity {up}"
    boxes = np.flatnonzero(m.geom_type == mujoco.mjtGeom.mjGEOM_BOX)
    signs = np.array(np.meshgrid([-1, 1], [-1, 1], [-1, 1])).reshape(3, -1).T
    corners = np.vstack([d.geom_xpos[g] + (signs * m.geom_size[g]) @ d.geom_xmat[g].reshape(3, 3).T
                         for g in boxes])
    height = (corners - d.geom_xpos[floor]) @ up
    assert np.min(height) > 0, f"{name}: a box corner {np.min(height):.3g} m below the floor"
    assert np.all(np.abs((corners - d.geom_xpos[floor]) @ d.geom_xmat[floor].reshape(3, 3)[:, :2])
                  <= m.geom_size[floor, :2]), f"{name}: the floor does not extend under every box"
    cam = m.camera("view").id
    R = d.cam_xmat[cam].reshape(3, 3)
    local = (corners - d.cam_xpos[cam]) @ R             # camera frame: looks along -z, y up
    half = np.tan(np.deg2rad(m.cam_fovy[cam]) / 2)
    depth = -local[:, 2]
    assert np.all(depth > 0), f"{name}: part of the scene behind the camera"
    assert np.max(np.abs(local[:, 1]) / depth) <= half, f"{name}: the scene leaves the camera's view vertically"
    assert np.max(np.abs(local[:, 0]) / depth) <= half * 4 / 3, \
        f"{name}: the scene leaves a 4:3 view horizontally"
    free = mujoco.MjvCamera()
    mujoco.mjv_defaultFreeCamera(m, free)
    assert np.allclose(free.lookat, m.stat.center) and free.distance == pytest.approx(
        np.linalg.norm(d.cam_xpos[cam] - m.stat.center), rel=1e-9), f"{name}: free camera ≠ fixed camera"


def test_viewer_launcher_starts_at_the_keyframe(monkeypatch, spatial):
    """`python -m coopsim.twin.mjcf FILE`: MuJoCo's viewer, loaded (and reloaded) at key 0, the loop closed."""
    import mujoco.viewer

    loaders = []
    monkeypatch.setattr(mujoco.viewer, "launch", lambda **kw: loaders.append(kw["loader"]))
    path = ROOT / "models" / "spatial_6r_pair.xml"
    launch_viewer(path)
    m, d, where = loaders[0]()
    assert where == str(path)
    gap = np.max(np.abs(d.qpos[qpos_address(m, spatial)] - initial_state(spatial).q))
    assert gap <= FILE_RTOL * np.max(np.abs(initial_state(spatial).q)), f"viewer qpos off the keyframe by {gap:.3g}"
    assert np.max(np.abs(d.efc_pos[: d.nefc])) <= 1e-12, "weld violation in the viewer's first frame"
