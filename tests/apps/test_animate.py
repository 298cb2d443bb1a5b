"""coopsim animate and view: a short GIF of the paper run through the real command (frame count, size,
motion, time stamp, the two models' agreement), the two models' silhouettes coinciding (and parting when
the twin is moved), one-line errors; the viewer opened at the keyframe. Skipped where MuJoCo's offscreen
renderer cannot start (no EGL/OSMesa)."""

from __future__ import annotations

import json
import math
import os
import shutil
import subprocess
import sys

import numpy as np
import pytest
from PIL import Image

from coopsim import cli
from coopsim.apps.animate import Motion, RenderUnavailable, motion_from_log, probe_renderer, render_frames
from coopsim.twin.harness import cross_validate
from coopsim.io.log import file_sha256, write_run_log
from coopsim.io.scenario import load_scenario
from helpers import ROOT, SCENARIOS

PAPER = "paper_planar_2x3"
DURATION, FPS, W, H = 1.0, 5.0, 240, 180


@pytest.fixture(scope="module")
def renderer():
    """Skip (with the reason) where no OpenGL backend starts; it must start on the development machine."""
    try:
        return probe_renderer()
    except RenderUnavailable as exc:
        pytest.skip(f"no offscreen OpenGL: {exc}")


@pytest.fixture(scope="module")
def paper_run(tmp_path_factory):
    """A folder with scenarios/ and the paper scenario's 1 s `coopsim run` log in out/NAME/ (as `run`
    writes it: scenario file relative to the folder, its sha256); the CrossValidation."""
    root = tmp_path_factory.mktemp("animate")
    shutil.copytree(SCENARIOS, root / "scenarios")
    scenario = root / "scenarios" / f"{PAPER}.yaml"
    model = load_scenario(scenario)
    cv = cross_validate(model, duration=DURATION)
    log = write_run_log(root / "out" / PAPER / f"{PAPER}.mcap", model, cv.native, cv.twin, metadata_extra={
        "scenario": {"file": f"scenarios/{PAPER}.yaml", "sha256": file_sha256(scenario)}})
    return root, log, cv


@pytest.fixture(scope="module")
def animate_command(paper_run):
    """`coopsim animate SCENARIO ... --out anim.gif --json` in the folder of `paper_run`, started at once
    (it runs while this process does its own checks); the Popen."""
    root = paper_run[0]
    proc = subprocess.Popen(
        [sys.executable, "-m", "coopsim.cli", "animate", f"scenarios/{PAPER}.yaml", "--duration", str(DURATION),
         "--fps", str(FPS), "--width", str(W), "--height", str(H), "--out", "anim.gif", "--json"],
        cwd=root, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    yield proc
    if proc.poll() is None:
        proc.kill()
    proc.communicate()


def _gif_frames(path) -> list[np.ndarray]:
    im = Image.open(path)
    frames = []
    for k in range(im.n_frames):
        im.seek(k)
        frames.append(np.asarray(im.convert("RGB"), dtype=np.int16))
    return frames


def _silhouette(frame: np.ndarray) -> np.ndarray:
    """Pixels that are not the plain background (the corner's colour)."""
    return np.abs(frame.astype(np.int16) - frame[0, 0].astype(np.int16)).sum(axis=2) > 12


def _iou(a: np.ndarray, b: np.ndarray) -> float:
    return float((a & b).sum() / (a | b).sum())


def test_gif_of_the_paper_run(paper_run, animate_command, renderer):
    """`coopsim animate SCENARIO` reuses the scenario's log in out/NAME/ and writes floor(duration·fps)+1
    frames of the requested size and frame time; the arms move between the first and last frame, the
    time stamp changes every frame while the scene away from the arms stays still; the reported joint-angle
    difference of the two models is the log's at the frame times (and within the scenario's threshold).
    The silhouettes of the native model and of the twin drawn alone coincide, and part when the twin's
    arm 2's first joint is turned by 0.05 rad (the check can fail)."""
    root, log, cv = paper_run
    out = root / "anim.gif"
    proc = animate_command
    try:
        # meanwhile, in this process: silhouettes of each model alone at t = 1 s
        motion = motion_from_log(log)
        assert motion.model.name == PAPER and np.array_equal(motion.q_native, cv.native.q)
        # at t = 0 and 1 both the native model at 1 s; the twin at 1 s, then turned at arm 2's base
        qn, qt = (q[0] for q in motion.at(np.array([DURATION])))
        two = Motion(motion.model, np.array([0.0, 1.0]), np.array([qn, qn]),
                     np.array([qt, qt + 0.05 * np.eye(6)[3]]), "two")
        alone = dict(floor=False, text=False, twin_sleeve=False)    # same camera: it frames both models
        both = np.array([0.0, 1.0])
        native = _silhouette(list(render_frames(two, both, W, H, twin=False, **alone))[0])
        twin, twin_moved = map(_silhouette, render_frames(two, both, W, H, native=False, **alone))
        assert native.sum() > 0.02 * W * H, "the native model is hardly drawn"
        assert _iou(native, twin) >= 0.98, f"native and twin silhouettes differ: IoU {_iou(native, twin):.3f}"
        assert _iou(native, twin_moved) <= 0.9, f"a moved twin still matches: IoU {_iou(native, twin_moved):.3f}"
    finally:
        stdout, stderr = proc.communicate(timeout=120)
    assert proc.returncode == 0, stderr
    report = json.loads(stdout)
    count = math.floor(DURATION * FPS) + 1
    assert report["frames"] == count and report["source"] == f"log out/{PAPER}/{PAPER}.mcap", report
    k = np.round(np.arange(count) / FPS / 0.01).astype(int)       # the frame times on the log's 0.01 s grid
    dq = np.max(np.abs(cv.native.q[k] - cv.twin.q[k]))
    assert report["max_angle_difference_rad"] == pytest.approx(dq, rel=1e-9) and dq < 1e-7, (dq, report)

    gif = Image.open(out)
    assert (gif.format, gif.size, gif.n_frames, gif.info["duration"]) == ("GIF", (W, H), count, 1000 / FPS)
    frames = _gif_frames(out)
    changed = np.abs(frames[-1] - frames[0]).sum(axis=2) > 60
    stamp = (slice(0, H // 8), slice(0, W // 3))                  # top left: "t = 0.00 s"
    corner = (slice(0, H // 5), slice(W - W // 5, W))             # top right: floor only
    body = changed.copy()
    body[stamp] = False
    body[H - H // 8:] = False                                     # legend and angle difference
    assert body.sum() >= 0.005 * W * H, f"the arms hardly move: {body.sum()} pixels changed"
    for a, b in zip(frames, frames[1:]):
        assert np.abs(a[stamp] - b[stamp]).sum() > 0, "the time stamp did not change"
        assert np.array_equal(a[corner], b[corner]), "the scene away from the arms moved"


def _main(capsys, *args) -> tuple[int, list[str]]:
    status = cli.main([*map(str, args)])
    return status, capsys.readouterr().err.strip().splitlines()


def test_errors_are_one_line(capsys, monkeypatch, paper_run, tmp_path):
    """Unknown suffix, missing file, MP4 without ffmpeg, a log whose scenario is not found or changed,
    a scenario with --scenario, `view` without a display, no OpenGL platform: exit 2 and one line naming
    the cause."""
    root, log, _ = paper_run
    scenario = root / "scenarios" / f"{PAPER}.yaml"
    status, err = _main(capsys, "animate", scenario, "--out", tmp_path / "x.avi")
    assert status == 2 and len(err) == 1 and "'.avi'" in err[0] and ".gif" in err[0], err
    status, err = _main(capsys, "animate", tmp_path / "missing.mcap")
    assert status == 2 and len(err) == 1 and "not found" in err[0], err
    monkeypatch.setenv("PATH", str(tmp_path))                    # no ffmpeg there
    status, err = _main(capsys, "animate", log, "--out", tmp_path / "x.mp4")
    assert status == 2 and len(err) == 1 and "ffmpeg" in err[0], err
    monkeypatch.undo()

    lone = tmp_path / "lone" / "run.mcap"                         # a log far from its scenario
    lone.parent.mkdir()
    shutil.copy(log, lone)
    monkeypatch.chdir(lone.parent)
    status, err = _main(capsys, "animate", lone)
    assert status == 2 and len(err) == 1 and "--scenario" in err[0], err
    edited = tmp_path / "lone" / "scenarios" / f"{PAPER}.yaml"     # found, but not the file of the run
    edited.parent.mkdir()
    edited.write_text(scenario.read_text().replace("duration: 5.0", "duration: 4.0"))
    status, err = _main(capsys, "animate", lone)
    assert status == 2 and len(err) == 1 and "changed" in err[0], err
    status, err = _main(capsys, "animate", scenario, "--scenario", scenario)
    assert status == 2 and len(err) == 1 and "--scenario" in err[0], err

    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    monkeypatch.setattr(sys, "platform", "linux")
    status, err = _main(capsys, "view", scenario)
    assert status == 2 and len(err) == 1 and "display" in err[0], err

    # no OpenGL platform (GLFW without a display): one line naming MUJOCO_GL and the packages, before
    # anything runs (the scenario has no log here), nothing written
    monkeypatch.setenv("MUJOCO_GL", "glfw")
    status, err = _main(capsys, "animate", scenario, "--out", tmp_path / "no_gl.gif")
    assert status == 2 and len(err) == 1, err
    assert "MUJOCO_GL=glfw" in err[0] and "libegl1" in err[0] and "libosmesa6" in err[0], err
    assert not (tmp_path / "no_gl.gif").exists()


def test_a_mujoco_gl_that_breaks_import_mujoco_is_one_line(tmp_path):
    """MUJOCO_GL naming a platform mujoco cannot load makes `import mujoco` itself fail: `coopsim animate`
    reports that as one line naming MUJOCO_GL (exit 2), whichever of the package's modules imports
    mujoco first."""
    env = {**os.environ, "MUJOCO_GL": "no_such_platform"}
    out = subprocess.run([sys.executable, "-m", "coopsim.cli", "animate", str(SCENARIOS / f"{PAPER}.yaml"), "--out",
                          str(tmp_path / "a.gif")], capture_output=True, text=True, env=env, timeout=120, cwd=ROOT)
    lines = out.stderr.strip().splitlines()
    assert out.returncode == 2 and len(lines) == 1, out.stderr
    assert "import mujoco failed with MUJOCO_GL='no_such_platform'" in lines[0], lines
    assert not (tmp_path / "a.gif").exists()


def test_view_opens_the_twin_at_the_keyframe(monkeypatch, capsys):
    """`coopsim view SCENARIO` hands MuJoCo's viewer the twin loaded at its keyframe: the loop closed."""
    import mujoco
    import mujoco.viewer

    from coopsim.apps.animate import viewer

    seen = []

    def launch(loader):
        m, d, _ = loader()
        seen.append(float(np.max(np.abs(d.efc_pos[: d.nefc]))))

    monkeypatch.setattr(mujoco.viewer, "launch", launch)
    monkeypatch.setattr(viewer, "has_display", lambda: True)
    monkeypatch.setattr(viewer, "_check_window", lambda: None)
    assert cli.main(["view", str(SCENARIOS / f"{PAPER}.yaml")]) == 0
    assert cli.main(["view", str(ROOT / "models" / f"{PAPER}.xml")]) == 0
    assert len(seen) == 2 and max(seen) <= 1e-12, seen


def _gold(frame: np.ndarray) -> np.ndarray:
    """The payload's gold pixels (frames.PAYLOAD_RGBA shaded), above the legend strip."""
    f = frame.astype(int)[: H - H // 8]
    return (f[..., 0] > 120) & (f[..., 1] > 90) & (f[..., 2] < 0.6 * f[..., 1])


def test_a_replayed_optimum_draws_its_payload_on_the_object(renderer):
    """A motion carrying a point payload (an optimum's replay log) draws a gold sphere on the object where the
    payload sits, and names its mass in the legend: no gold pixel without it, a blob with it, which moves
    with the payload from the bar's right end (0.2 m) to its left end (−0.2 m)."""
    from coopsim.apps.animate.frames import payload_label
    from coopsim.apps.animate.motion import Payload

    model = load_scenario(SCENARIOS / "paper_planar_2x3_carry.yaml")
    q = np.array([model.q0, model.q0])
    t = np.array([0.0, 1.0])

    def frame(payload):
        motion = Motion(model, t, q, q, "test", payload)
        return list(render_frames(motion, t[:1], W, H))[0]

    bare, right, left = (frame(p) for p in (None, Payload(206.04, "payload", np.array([0.2, 0.0, 0.0])),
                                            Payload(206.04, "payload", np.array([-0.2, 0.0, 0.0]))))
    assert _gold(bare).sum() == 0
    assert _gold(right).sum() >= 100 and _gold(left).sum() >= 100
    column = lambda f: np.nonzero(_gold(f))[1].mean()        # noqa: E731
    assert column(right) - column(left) >= 0.1 * W, (column(right), column(left))
    assert payload_label(Payload(206.04, "payload", np.zeros(3))) == "payload 206.04 kg"
    assert payload_label(Payload(12.3, "scaled", None)) == "object 12.3 kg (scaled)"
