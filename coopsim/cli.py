"""Command-line interface: thin dispatch over the library (`coopsim --help`)."""

from __future__ import annotations

import argparse
import contextlib
import json
import signal
import sys
import warnings

from coopsim import __version__
from coopsim.core.errors import CoopsimError
from coopsim.inverse.resolutions import LINEAR_METHODS as LINEAR_METHODS_CLI, METHODS, methods_help


def _cmd_simulate(args) -> int:
    from coopsim.apps.progress import ProgressBar
    from coopsim.control.controller import closed_loop
    from coopsim.io.scenario import load_scenario
    from coopsim.forward.simulate import simulate
    from coopsim.report.summary import format_simulation_summary, simulation_summary

    model = closed_loop(load_scenario(args.scenario, duration=args.duration, overrides=_overrides(args)))
    with ProgressBar(enabled=not args.json) as bar:
        res = simulate(model, duration=args.duration, progress=lambda f: bar("native", f))
        bar("native", 1.0)
    summary = simulation_summary(res)
    print(json.dumps(summary, indent=2) if args.json else format_simulation_summary(summary))
    _print_warnings(res)
    return 0


def _print_warnings(res) -> None:
    """Each warning of a native run (`coopsim.forward.diagnostics`) as one line on stderr."""
    for w in res.warnings:
        print(f"coopsim: warning: {w.message()}", file=sys.stderr)


def _write_set(out, index: str, log_name: str, streams, meta, draw, workers, summarize, during=lambda: None,
               also=lambda stage, log: None):
    """Write a command's outputs into folder `out` as one set (`staged_folder`: all of them or none, the
    previous set listed in `index` replaced): the MCAP log `log_name` of (streams, meta), the figures of
    draw(log, folder, workers=workers) drawn from the in-memory log meanwhile (`render_while`), and
    the JSON summary `index`, summarize(log path, plot paths) (their final paths) → its text. `during()`
    runs here while the figures are drawn, before the log is written (work that the log does not
    hold); also(stage folder, in-memory log) then writes any further outputs of the set (the ROS 2 bag).
    Returns (log path, plot paths); a failure to write is one line naming --out (`_writing`)."""
    from coopsim.io.atomic import previous_set, staged_folder, write_text_atomic
    from coopsim.io.mcap_codec import log_data, write_mcap
    from coopsim.plots.render import render_while

    def work():
        during()
        also(stage, log_data(streams, meta, messages=False))
        return write_mcap(stage / log_name, streams, meta)

    with _writing(out), staged_folder(out, replaces=previous_set(index)) as stage:
        plots, log_path = render_while(lambda: draw(log_data(streams, meta, messages=False), stage, workers=workers),
                                       work)
        log_path, plots = out / log_path.name, [out / p.name for p in plots]
        write_text_atomic(stage / index, summarize(log_path, plots))
    return log_path, plots


def _check_out(out) -> None:
    """Refuse an output folder `out` that cannot take a command's set of files, before the work: one line
    naming --out (`coopsim.io.atomic.folder_problem`)."""
    from coopsim.io.atomic import folder_problem

    if problem := folder_problem(out):
        raise CoopsimError(f"--out {out}: {problem}")


@contextlib.contextmanager
def _writing(out):
    """Re-raise an OSError of the block, which writes a set of files as folder `out`, as one line naming --out
    and why (what is in the way, else the system's reason), never a temporary's name."""
    from coopsim.io.atomic import folder_problem

    try:
        yield
    except OSError as exc:
        raise CoopsimError(f"--out {out}: {folder_problem(out) or exc.strerror or exc}") from exc


def _cmd_mjcf(args) -> int:
    from pathlib import Path

    from coopsim.io.atomic import write_text_atomic
    from coopsim.twin.mjcf import mjcf_text
    from coopsim.twin.weld import resolved
    from coopsim.apps.progress import ProgressBar
    from coopsim.io.scenario import load_scenario

    _announce_compile()                     # the keyframes come from the native model's initial state
    overrides = _overrides(args)
    scenarios = _scenario_paths(args.scenarios)
    paths = []
    with ProgressBar() as bar:
        for i, scenario in enumerate(scenarios):   # drawn after each file: a first-run compile notice comes first
            path = Path(args.out) / f"{Path(scenario).stem}.xml"
            model = resolved(load_scenario(scenario, overrides=overrides))   # an automatic step: a native run
            write_text_atomic(path, mjcf_text(model, _display_path(scenario)))
            paths.append(path)
            bar("mjcf", (i + 1) / len(scenarios))
    print("\n".join(map(str, paths)))     # after the bar: the paths never share its line
    return 0


def _cmd_urdf(args) -> int:
    from pathlib import Path

    from coopsim.io.atomic import write_text_atomic
    from coopsim.io.scenario import load_scenario
    from coopsim.io.urdf import urdf_text

    model = load_scenario(args.scenario, overrides=_overrides(args))
    path = write_text_atomic(Path(args.out or Path("out") / model.name / f"{model.name}.urdf"), urdf_text(model))
    print(path)
    return 0


def _cmd_run(args) -> int:
    from dataclasses import replace
    from pathlib import Path

    from coopsim.twin.harness import control_series, cross_validate
    from coopsim.io.log import file_sha256, run_log
    from coopsim.io.ros2 import VERDICT_RECORD, write_bag
    from coopsim.plots.run import comparison_plots
    from coopsim.apps.progress import ProgressBar
    from coopsim.plots.render import FigureWorkers
    from coopsim.io.scenario import load_scenario
    from coopsim.report.summary import run_summary

    model = load_scenario(args.scenario, duration=args.duration, overrides=_overrides(args))
    out = Path(args.out or Path("out") / model.name)   # made by the first write: a failed run leaves none
    _check_out(out)
    with FigureWorkers() as workers:
        bar = ProgressBar(enabled=not args.json)
        cv = cross_validate(model, duration=args.duration, progress=bar)
        bar.close()
        streams, meta = run_log(replace(model, mujoco=cv.mujoco), cv.native, cv.twin, extra_series=control_series(cv),
                                metadata_extra={
            "scenario": {"file": _display_path(args.scenario), "sha256": file_sha256(args.scenario)}
            | ({"overrides": list(args.set)} if args.set else {}),
            "native_engine": cv.native.engine,
            "agreement": {k: f"{m['max']!r}" for k, m in cv.comparison.as_dict()["metrics"].items()},
            VERDICT_RECORD: {"passed": cv.comparison.passed, "failures": cv.comparison.failures(),
                             "metrics": cv.comparison.as_dict()["metrics"]}}
            | ({} if cv.step is None else {"mujoco.step": cv.step.as_dict()}))
        summary: dict = {}
        bag = f"{model.name}_ros2"

        def summarize(log_path, plots) -> str:
            summary.update(run_summary(cv, log_path, plots))
            if args.ros2:
                summary["files"]["ros2"] = str(out / bag)
            return json.dumps(summary, indent=2) + "\n"

        def ros2(stage, log) -> None:
            if args.ros2:
                write_bag(stage / bag, model, log)

        log_path, plots = _write_set(out, "summary.json", f"{model.name}.mcap", streams, meta, comparison_plots,
                                     workers, summarize, also=ros2)
    _print_warnings(cv.native)
    if args.json:
        print(json.dumps(summary, indent=2))
    else:
        _print_comparison(cv)
        print(f"wall time: native {cv.native.wall_time:.2f} s, MuJoCo {cv.twin.wall_time:.2f} s")
        bag_note = f", the ROS 2 bag {out / bag}" if args.ros2 else ""
        print(f"wrote {log_path}, {out / 'summary.json'}{bag_note} and {len(plots)} plots in {out}")
    return 0 if cv.comparison.passed else 1


def _cmd_export_ros2(args) -> int:
    from pathlib import Path

    from coopsim.io.log import log_model, read_run_log
    from coopsim.io.ros2 import export_bag

    log_path = Path(args.log)
    if not log_path.is_file():
        raise CoopsimError(f"{log_path}: log file not found")
    log = read_run_log(log_path)
    print(export_bag(Path(args.out), log_model(log_path, log, args.scenario), log))
    return 0


def _cmd_plot(args) -> int:
    from pathlib import Path

    from coopsim.io.log import read_run_log
    from coopsim.plots.run import comparison_plots
    from coopsim.apps.progress import ProgressBar

    log_path = Path(args.log)
    if not log_path.is_file():
        raise CoopsimError(f"{log_path}: log file not found")
    with ProgressBar() as bar:
        bar("read log", 0.0)
        log = read_run_log(log_path)
        bar("read log", 1.0)
        bar("figures", 0.0)
        paths = comparison_plots(log, Path(args.out or log_path.parent))
        bar("figures", 1.0)
    for path in paths:
        print(path)
    return 0


def _print_comparison(cv) -> None:
    """The comparison table of a CrossValidation, its twin's step when chosen or explained, its failures."""
    from coopsim.twin.compare import format_comparison
    from coopsim.twin.weld import describe

    print(format_comparison(cv.comparison))
    if cv.step is not None:
        print(f"  {describe(cv.step)}")
    for failure in cv.comparison.failures():
        print(f"  FAIL: {failure}")


def _cmd_validate(args) -> int:
    from coopsim.twin.harness import cross_validate
    from coopsim.apps.progress import ProgressBar
    from coopsim.io.scenario import load_scenario

    results, overrides = [], _overrides(args)
    for scenario in _scenario_paths(args.scenarios, hard=True):
        bar = ProgressBar(enabled=not args.json)
        cv = cross_validate(load_scenario(scenario, duration=args.duration, overrides=overrides),
                            duration=args.duration, progress=bar)
        bar.close()
        results.append(cv.comparison)
        if not args.json:
            _print_comparison(cv)
    ok = all(c.passed for c in results)
    if args.json:
        print(json.dumps({"passed": ok, "scenarios": [c.as_dict() for c in results]}, indent=2))
    else:
        print(f"cross-validation: {sum(c.passed for c in results)}/{len(results)} scenarios agree")
    return 0 if ok else 1


def _cmd_inverse(args) -> int:
    from pathlib import Path

    from coopsim.report.inverse_report import (add_checks, format_inverse_summary, inverse_series, inverse_summary,
                                               json_safe, solve_study)
    from coopsim.io.log import file_sha256, run_metadata
    from coopsim.plots.inverse import inverse_plots
    from coopsim.apps.progress import ProgressBar
    from coopsim.plots.render import FigureWorkers
    from coopsim.io.scenario import load_scenario

    model = load_scenario(args.scenario, duration=args.duration, overrides=_overrides(args))
    methods = METHODS if args.method == "all" else (args.method,)
    if args.torques_csv is not None and args.method == "all":
        raise CoopsimError("--torques-csv: name the resolution to export with --method")
    out = Path(args.out or Path("out") / model.name)
    _check_out(out)
    with FigureWorkers() as workers:
        bar = ProgressBar(enabled=not args.json)
        study = solve_study(model, methods, duration=args.duration, bounds=(args.bound_force, args.bound_moment),
                            progress=bar)
        streams, meta = inverse_series(study), run_metadata(model, study.sim, {
            "scenario": {"file": _display_path(args.scenario), "sha256": file_sha256(args.scenario)},
            "inverse": {"methods": list(methods), "force_bound_N": study.bounds[0],
                        "moment_bound_Nm": study.bounds[1]}})
        summary: dict = {}

        def checks():   # replays and trade-off curve (not in the log): computed while the figures are drawn
            summary.update(inverse_summary(add_checks(study, args.replay, not args.no_curve, bar)))
            bar.close()

        log_path, plots = _write_set(out, "inverse.json", "inverse.mcap", streams, meta, inverse_plots, workers,
                                     lambda log_path, plots: _summary_text(summary, log_path, plots,
                                                                           out / "inverse.json"),
                                     during=checks)
    print(json.dumps(json_safe(summary), indent=2) if args.json else
          format_inverse_summary(summary)
          + f"\nwrote {log_path}, {out / 'inverse.json'} and {len(plots)} plots in {out}")
    if args.torques_csv is not None:
        from coopsim.io.torque_csv import write_torque_csvs

        res = study.results[args.method]
        paths = write_torque_csvs(args.torques_csv, model, res.t - res.t[0], res.tau)
        print(f"wrote {', '.join(map(str, paths))}", file=sys.stderr if args.json else sys.stdout)
    return 0 if summary.get("complete", True) else 1


def _summary_text(summary: dict, log_path, plots, index) -> str:
    """The JSON text of an inverse or capacity summary, its "files" (log, plots, the summary) set first."""
    from coopsim.report.inverse_report import json_safe

    summary["files"] = [str(log_path)] + [str(p) for p in plots] + [str(index)]
    return json.dumps(json_safe(summary), indent=2) + "\n"


def _cmd_capacity(args) -> int:
    from pathlib import Path

    import numpy as np

    from coopsim.report.inverse_report import (capacity_metadata, capacity_series, capacity_study, capacity_summary,
                                 format_capacity_summary, json_safe)
    from coopsim.io.log import file_sha256, run_metadata
    from coopsim.plots.inverse import capacity_plots
    from coopsim.apps.progress import ProgressBar
    from coopsim.plots.render import FigureWorkers
    from coopsim.io.scenario import load_scenario, require_motor_limits

    model = load_scenario(args.scenario, duration=args.duration, overrides=_overrides(args))
    require_motor_limits(model, args.scenario)
    payload = None if args.payload is None else np.array(args.payload, dtype=float)
    out = Path(args.out or Path("out") / model.name)
    _check_out(out)
    with FigureWorkers() as workers:
        bar = ProgressBar(enabled=not args.json)
        study = capacity_study(model, duration=args.duration, payload_position=payload, with_lp=not args.no_lp,
                               optimise=not args.no_optimise, check=args.check, progress=bar)
        bar.close()
        summary = capacity_summary(study)
        meta = {"scenario": {"file": _display_path(args.scenario), "sha256": file_sha256(args.scenario)}}
        streams, meta = capacity_series(study), run_metadata(model, None, meta | capacity_metadata(summary))
        log_path, plots = _write_set(out, "capacity.json", "capacity.mcap", streams, meta, capacity_plots, workers,
                                     lambda log_path, plots: _summary_text(summary, log_path, plots,
                                                                           out / "capacity.json"))
    print(json.dumps(json_safe(summary), indent=2) if args.json else
          format_capacity_summary(summary)
          + f"\nwrote {log_path}, {out / 'capacity.json'} and {len(plots)} plots in {out}")
    ok = all(v["ok"] for v in summary.get("brute_force_check", {}).values())
    return 0 if ok else 1


def _cmd_optimize(args) -> int:
    from pathlib import Path

    from coopsim.apps.progress import ProgressBar
    from coopsim.io.atomic import write_text_atomic
    from coopsim.io.log import file_sha256, run_metadata
    from coopsim.io.mcap_codec import write_mcap
    from coopsim.io.overrides import apply_overrides
    from coopsim.io.scenario import load_scenario, require_motor_limits, scenario_text
    from coopsim.io.yaml_rules import load_yaml
    from coopsim.inverse.free_path import PathOptimizationError
    from coopsim.plots.free_path import path_jobs
    from coopsim.plots.optimize import optimize_jobs
    from coopsim.plots.render import FigureWorkers, render_figures
    from coopsim.report.path_report import (format_path_summary, path_metadata, path_scenario, path_series,
                                            path_study, path_summary)
    from coopsim.report.inverse_report import json_safe
    from coopsim.report.optimize_report import (format_retime_summary, optimised_scenario, retime_metadata,
                                                retime_series, retime_study, retime_summary, with_energy_weights)
    from coopsim.report.closed_replay import (closed_metadata, closed_replay_of, closed_series, format_replay_entry,
                                              replay_entry)
    from coopsim.report.optimum_replay import optimum_replay, path_replay, replay_run_log

    if not (args.retime or args.path):
        raise CoopsimError("optimize: give --retime (the fixed path's time law) and/or --path (the free path)")
    if args.closed_loop and not args.replay:
        raise CoopsimError("--closed-loop: replays the optimum under feedback; give it with --replay")
    if args.weights and args.method != "min_energy":
        raise CoopsimError("--weights: the energy weights are the minimum energy's; give --method min_energy")
    for name in ("duration", "payload"):
        value = getattr(args, name)
        if value is not None and not (value > 0 if name == "duration" else value >= 0):
            raise CoopsimError(f"--{name}: must be {'positive' if name == 'duration' else 'non-negative'}, "
                               f"got {value:g}")
    if args.intervals < 2:
        raise CoopsimError(f"--intervals: at least 2, got {args.intervals}")
    model = load_scenario(args.scenario, overrides=_overrides(args))
    require_motor_limits(model, args.scenario)
    if model.inverse.object_motion is None:
        raise CoopsimError(f"{args.scenario}: inverse.object_motion: optimize needs an object motion (its waypoints)")
    out = Path(args.out or Path("out") / model.name / "optimize")
    _check_out(out)
    with FigureWorkers() as workers:
        bar = ProgressBar(enabled=not args.json)
        study = None if not args.retime else retime_study(model, duration=args.duration, payload=args.payload,
                                                           method=args.method, intervals=args.intervals,
                                                           weights=args.weights, progress=bar)
        rep = optimum_replay(study, progress=bar) if args.replay and study is not None else None
        free = None if not args.path else path_study(model, args.method, weights=args.weights,
                                                     duration=args.duration, progress=bar)
        if free is not None and not free.optimum.best.success:
            bar.close()
            best = free.optimum.best
            raise PathOptimizationError(f"optimize --path: the free-path optimiser did not converge: its best run "
                                        f"(K = {best.control_points}, {best.iterations} iteration{'' if best.iterations == 1 else 's'}) ended with SLSQP "
                                        f"{best.message}; nothing written")
        free_rep = path_replay(free, progress=bar) if args.replay and free is not None else None
        rep_closed, free_closed = (None if r is None else closed_replay_of(model, r, args.closed_loop)
                                   for r in (rep, free_rep))
        rep_entry, free_entry = (None if r is None else replay_entry(r, c) for r, c in
                                 ((rep, rep_closed), (free_rep, free_closed)))
        bar.close()
        summary = retime_summary(study) if study is not None else {"scenario": model.name}
        if free is not None:
            summary["path"] = path_summary(free)
        if free_entry is not None:
            summary["path"]["replay"] = free_entry
        if rep_entry is not None:
            summary["replay"] = rep_entry
        data = load_yaml(Path(args.scenario))
        if args.set:
            data = apply_overrides(data, _overrides(args), where=f"{args.scenario}: --set")
        texts = {}
        if study is not None:
            retimed = optimised_scenario(data, study.motion)
            if study.weights is not None:
                retimed = with_energy_weights(retimed, model, study.weights.weights)
            texts[f"{model.name}_retimed.yaml"] = scenario_text(
                retimed, f"{_display_path(args.scenario)} retimed by coopsim optimize --retime (the {args.method} "
                         f"time law{', its energy weights' if study.weights is not None else ''})")
        if free is not None:
            freed = path_scenario(data, free.motion)
            if args.weights:
                freed = with_energy_weights(freed, model, free.optimum.resolution.weights)
            texts[f"{model.name}_path.yaml"] = scenario_text(
                freed, f"{_display_path(args.scenario)} with the free path of coopsim optimize --path (the "
                       f"{args.method} resolution{', its energy weights' if args.weights else ''})")
        meta = {"scenario": {"file": _display_path(args.scenario), "sha256": file_sha256(args.scenario)}
                | ({"overrides": list(args.set)} if args.set else {})}
        run_files = {r.log: replay_run_log(r, dict(meta) | ({} if c is None else closed_metadata(c)),
                                           () if c is None else closed_series(c))
                     for r, c in ((rep, rep_closed), (free_rep, free_closed)) if r is not None}
        meta |= retime_metadata(summary) if study is not None else {}
        meta |= path_metadata(summary["path"]) if free is not None else {}
        streams = (retime_series(study) if study is not None else []) + (path_series(free) if free is not None else [])
        meta = run_metadata(model, None, meta)

        def draw(log, folder, workers=None):
            jobs = (optimize_jobs(log, folder) if study is not None else []) + path_jobs(log, folder)
            return render_figures(jobs, workers)

        def summarize(log_path, plots):
            summary["optimised_scenarios"] = [str(out / n) for n in texts]
            if study is not None:
                summary["optimised_scenario"] = str(out / f"{model.name}_retimed.yaml")
            for entry in (summary.get("replay"), summary.get("path", {}).get("replay")):
                if entry is not None:
                    entry["log"] = str(out / entry["log"])
            return _summary_text(summary, log_path, plots, out / "optimize.json")

        def also(stage, log):
            for n, text in texts.items():
                write_text_atomic(stage / n, text)
            for n, (run_streams, run_meta) in run_files.items():
                write_mcap(stage / n, run_streams, run_meta)

        log_path, plots = _write_set(out, "optimize.json", "optimize.mcap", streams, meta, draw, workers,
                                     summarize, also=also)
    text = "\n".join(([format_retime_summary(summary)] if study is not None else [])
                     + ([format_replay_entry(summary["replay"])] if rep is not None else [])
                     + ([format_path_summary(summary["path"])] if free is not None else [])
                     + ([format_replay_entry(summary["path"]["replay"])] if free_rep is not None else []))
    print(json.dumps(json_safe(summary), indent=2) if args.json else
          text + f"\nwrote {', '.join(str(out / n) for n in [*texts, *run_files])}, {log_path}, {out / 'optimize.json'} and "
                 f"{len(plots)} plots in {out}")
    return 0


def _cmd_sweep(args) -> int:
    from pathlib import Path

    from coopsim.apps.progress import ProgressBar
    from coopsim.apps.sweep import load_sweep
    from coopsim.apps.sweep_run import require_packages, run_sweep, write_outputs

    if sum([args.serial, args.scheduler is not None, args.workers is not None]) > 1:
        raise CoopsimError("--serial, --workers and --scheduler: give at most one")
    require_packages(dask=not args.serial)
    sweep = load_sweep(args.sweep, overrides=_overrides(args))
    out = Path(args.out or Path("out") / sweep.name)
    _check_out(out)
    with ProgressBar(enabled=not args.json) as bar:
        run = run_sweep(sweep, out, serial=args.serial, scheduler=args.scheduler, workers=args.workers,
                        resume=args.resume, progress=lambda f: bar("sweep", f))
    with _writing(out):
        paths = write_outputs(sweep, run, out)
    summary = json.loads((out / "sweep.json").read_text(encoding="utf-8"))
    if args.json:
        print(json.dumps(summary, indent=2))
    else:
        print(f"{sweep.name}: {summary['points']} points ({run.computed} run, {run.resumed} resumed from the "
              f"checkpoint, {summary['failed']} failed) on {run.executor} in {run.wall_time_s:.1f} s")
        for f in summary["failed_points"][:5]:
            print(f"  point {f['point']}: {f['error']}")
        print(f"wrote {len(paths)} files in {out}")
    return 0


def _cmd_bench(args) -> int:
    from coopsim.apps.bench import FULL, QUICK, run_bench
    from coopsim.apps.bench.report import json_text, markdown_report, write_outputs
    from coopsim.apps.progress import ProgressBar

    stage: list[str] = []

    def log(msg: str) -> None:       # one bar per stage (on a terminal), ended with the time it took
        if stage:
            bar(stage.pop(), 1.0)
        stage.append(msg)
        bar(msg, 0.0)

    with ProgressBar(enabled=not args.json) as bar:
        report = run_bench(_scenario_paths(args.scenarios), QUICK if args.quick else FULL, log=log)
        if stage:
            bar(stage.pop(), 1.0)
    paths = write_outputs(report, args.out)
    print(json_text(report) if args.json else markdown_report(report) + f"\nwrote {len(paths)} files in {args.out}")
    return 0


def _cmd_animate(args) -> int:
    import time
    from pathlib import Path

    from coopsim.apps.animate import check_output

    source = Path(args.source)
    if args.out is not None:
        check_output(args.out)              # a wrong suffix or a missing ffmpeg fails before any work
    if not source.is_file():
        raise CoopsimError(f"{source}: file not found")
    for name in ("fps", "speed"):
        if not getattr(args, name) > 0:
            raise CoopsimError(f"--{name}: must be positive, got {getattr(args, name):g}")
    if args.duration is not None and not args.duration > 0:
        raise CoopsimError(f"--duration: must be positive, got {args.duration:g}")
    from coopsim.apps.animate import animate, motion_from_log, probe_renderer, scenario_motion
    from coopsim.apps.progress import ProgressBar

    start = time.perf_counter()
    probe_renderer()                        # no OpenGL: one line now, not after running the models
    bar = ProgressBar(enabled=not args.json)
    overrides = _overrides(args)
    if source.suffix.lower() == ".mcap":
        if overrides:
            raise CoopsimError("--set: a log is drawn as it was run; give the scenario instead to run it with --set")
        motion = motion_from_log(source, scenario=args.scenario, closed_loop=args.closed_loop)
        out = Path(args.out or source.parent / f"{motion.model.name}.gif")
    else:
        if args.scenario is not None:
            raise CoopsimError("--scenario: only with a LOG.mcap source (the source is already a scenario)")
        if args.closed_loop:
            raise CoopsimError("--closed-loop: draws the closed loop of an optimum's run log (LOG.mcap of "
                               "`coopsim optimize --replay`), not a scenario")

        def before_run():
            _announce_compile()
            if not args.json:
                print(f"coopsim: no log of {source} in out/ (coopsim run): running both models", file=sys.stderr)

        motion = scenario_motion(source, duration=args.duration, progress=bar, before_run=before_run,
                                 overrides=overrides)
        out = Path(args.out or Path("out") / motion.model.name / f"{motion.model.name}.gif")
    check_output(out)
    result = animate(motion, out, fps=args.fps, speed=args.speed, duration=args.duration, width=args.width,
                     height=args.height, progress=lambda f: bar("render", f))
    bar.close()
    if args.json:
        print(json.dumps(result.as_dict() | {"wall_time_s": time.perf_counter() - start}, indent=2))
    else:
        dq = "" if result.max_angle_difference is None else \
            f"; max |q_native - q_MuJoCo| {result.max_angle_difference:.1e} rad"
        print(f"wrote {result.path}: {result.frames} frames {result.width}x{result.height} at {result.fps:g} fps "
              f"({result.span:.2f} s of the run, from the {result.source}); rendered in {result.render_time:.1f} s, "
              f"written in {result.write_time:.1f} s{dq}")
    return 0


def _cmd_view(args) -> int:
    from coopsim.apps.animate import view

    overrides = _overrides(args)
    if not args.source.lower().endswith(".xml"):
        _announce_compile()                 # the scenario's initial state comes from the native model
    elif overrides:
        raise CoopsimError("--set: applies to a scenario, not to an MJCF file")
    view(args.source, label=_display_path(args.source), overrides=overrides)
    return 0


def _overrides(args) -> list:
    """The command's `--set PATH=VALUE` options as (PATH, value) pairs (`coopsim.io.overrides`), in order."""
    from coopsim.io.overrides import parse_assignment

    return [parse_assignment(text) for text in args.set or ()]


def _add_set(p: argparse.ArgumentParser) -> None:
    p.add_argument("--set", action="append", metavar="PATH=VALUE",
                   help="override a scenario field before it is validated (repeatable; a later one wins), e.g. "
                        "--set object.box.density=2700 --set 'arms[1].motors.stall_torque[0]=0.7'; VALUE is YAML")


def _scenario_paths(given: list[str], hard: bool = False) -> list[str]:
    """The given scenario files, or every bundled `scenarios/*.yaml` when none is given (with `hard`,
    also the hard cases `scenarios/hard/*.yaml` that set `validation` thresholds: those with a
    meaningful MuJoCo twin)."""
    from pathlib import Path

    from coopsim.io.yaml_rules import load_yaml

    if given:
        return given
    found = sorted(str(p) for p in Path("scenarios").glob("*.yaml"))
    if hard:
        found += sorted(str(p) for p in Path("scenarios/hard").glob("*.yaml")
                        if isinstance(data := load_yaml(p), dict) and "validation" in data)
    if not found:
        raise CoopsimError("no scenario given and no scenarios/*.yaml in the current folder")
    return found


def _display_path(path: str) -> str:
    """`path` relative to the current folder when inside it (stable text in generated files)."""
    from pathlib import Path

    p = Path(path).resolve()
    try:
        return p.relative_to(Path.cwd()).as_posix()
    except ValueError:
        return p.as_posix()


class _Parser(argparse.ArgumentParser):
    """argparse with its usage errors on one line (`coopsim: error: …`, naming the option), exit 2."""

    def error(self, message: str):
        self.exit(2, f"coopsim: error: {' '.join(message.split())} (see {self.prog} --help)\n")


def build_parser() -> argparse.ArgumentParser:
    """The `coopsim` argument parser: one subcommand per command, each with its options and help.

    The commands are simulate, run, export-ros2, plot, validate, mjcf, urdf, inverse, capacity, optimize, sweep,
    bench, animate and view; each sets `func` (its handler, called with the parsed arguments) and, when it
    runs the native model, `native` (then `main` announces a first run's compilation). Usage errors print
    one line and exit 2.

    Returns:
        argparse.ArgumentParser: the parser (prog 'coopsim').
    """
    parser = _Parser(prog="coopsim", description=(
        "Cooperative manipulators: recursive Gibbs-Appell closed-chain dynamics, validated against MuJoCo."))
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    sub = parser.add_subparsers(dest="command")
    p = sub.add_parser("simulate", help="forward-simulate a scenario with the native model and print a summary",
                       description="Forward-simulate SCENARIO (YAML) with the native closed-chain model.")
    p.add_argument("scenario", help="scenario YAML file")
    p.add_argument("--duration", type=float, default=None, help="override the scenario's duration (s)")
    p.add_argument("--json", action="store_true", help="print a machine-readable JSON summary")
    _add_set(p)
    p.set_defaults(func=_cmd_simulate, native=True)

    p = sub.add_parser("run", help="run the native model and the MuJoCo twin: MCAP log, plots, summary.json",
                       description=("Run SCENARIO through the native model and its MuJoCo twin with the same "
                                    "torques; write DIR/NAME.mcap, comparison plots and summary.json; exit 0 "
                                    "only if the two agree within the scenario's thresholds."))
    p.add_argument("scenario", help="scenario YAML file")
    p.add_argument("--out", default=None, help="output folder (default: out/NAME)")
    p.add_argument("--duration", type=float, default=None, help="override the scenario's duration (s)")
    p.add_argument("--json", action="store_true", help="print summary.json to stdout")
    p.add_argument("--ros2", action="store_true",
                   help="also write the run as a ROS 2 bag (rosbag2 folder DIR/NAME_ros2: metadata.yaml and "
                        "one MCAP file of standard messages, the scene's URDF on /robot_description)")
    _add_set(p)
    p.set_defaults(func=_cmd_run, native=True)

    p = sub.add_parser("export-ros2", help="convert a run log (LOG.mcap) into a ROS 2 bag folder",
                       description=("Write LOG (an MCAP log of `coopsim run`) as a rosbag2 folder OUT_DIR "
                                    "(metadata.yaml and OUT_DIR_0.mcap: joint states, TF, object pose and twist, "
                                    "wrenches, the URDF, diagnostics, /clock; simulation time from 0), as "
                                    "`coopsim run --ros2` does. The geometry comes from the scenario file the log "
                                    "names (checked against its sha256) or --scenario."))
    p.add_argument("log", help="MCAP log file of `coopsim run`")
    p.add_argument("out", metavar="OUT_DIR", help="the bag folder to write (its other files are kept)")
    p.add_argument("--scenario", default=None, help="the scenario file to take the geometry from, in place of "
                                                   "the one the log names (no sha256 check)")
    p.set_defaults(func=_cmd_export_ros2)

    p = sub.add_parser("plot", help="comparison plots from an existing MCAP log",
                       description="Draw the comparison plots of LOG (an MCAP file written by `coopsim run`).")
    p.add_argument("log", help="MCAP log file")
    p.add_argument("--out", default=None, help="output folder (default: the log's folder)")
    p.set_defaults(func=_cmd_plot)

    p = sub.add_parser("validate", help="cross-validate scenarios against their MuJoCo twins",
                       description=("Run the native model and the MuJoCo twin of each SCENARIO (default: "
                                    "scenarios/*.yaml and the hard cases in scenarios/hard/ that set validation "
                                    "thresholds) and compare them; exit 0 only if all agree."))
    p.add_argument("scenarios", nargs="*", help="scenario YAML files")
    p.add_argument("--duration", type=float, default=None, help="override the scenarios' duration (s)")
    p.add_argument("--json", action="store_true", help="print a machine-readable JSON table")
    _add_set(p)
    p.set_defaults(func=_cmd_validate, native=True)

    p = sub.add_parser("mjcf", help="write the MuJoCo twin of scenarios as MJCF (models/NAME.xml)",
                       description="Write the MuJoCo twin (MJCF) of each SCENARIO (default: scenarios/*.yaml).")
    p.add_argument("scenarios", nargs="*", help="scenario YAML files")
    p.add_argument("--out", default="models", help="output folder (default: models)")
    _add_set(p)
    p.set_defaults(func=_cmd_mjcf)

    p = sub.add_parser("urdf", help="write the scene as a URDF (each arm an open chain, the object on the carrier)",
                       description=("Write SCENARIO as a URDF: each arm an open chain of its links (inertias, box "
                                    "visuals) from the link 'world', the object a link fixed to the carrier's end "
                                    "effector; the robot_description of `coopsim run --ros2`'s bag."))
    p.add_argument("scenario", help="scenario YAML file")
    p.add_argument("--out", default=None, help="output file (default: out/NAME/NAME.urdf)")
    _add_set(p)
    p.set_defaults(func=_cmd_urdf)

    p = sub.add_parser("inverse", help="inverse dynamics with redundancy resolution, internal wrench, object stress",
                       description=("Invert SCENARIO's trajectory (its forward run, or its prescribed object motion "
                                    "through closed-chain IK) with each redundancy resolution; print torques, "
                                    "energy, internal wrench and object stress; write DIR/inverse.mcap, plots and "
                                    "inverse.json."))
    p.add_argument("scenario", help="scenario YAML file")
    p.add_argument("--method", default="all", choices=("all",) + METHODS,
                   help=f"resolution (default: all): {methods_help()}")
    p.add_argument("--bound-force", type=float, default=None,
                   help="internal-force bound of 'bounded', N (default: scenario, else half the minimum-energy peak)")
    p.add_argument("--bound-moment", type=float, default=None,
                   help="internal-moment bound of 'bounded', N·m (default: scenario, else half the "
                        "minimum-energy peak)")
    p.add_argument("--replay", action="store_true",
                   help="feed each resolution's torques back through the forward dynamics and report the error")
    p.add_argument("--no-curve", action="store_true", help="skip the energy-against-bound sweep")
    p.add_argument("--torques-csv", default=None, metavar="PREFIX",
                   help="also write the torques of --method (one resolution) at the trajectory's samples as "
                        "PREFIX_ARM.csv per arm, the files a scenario's torque: {csv: ...} reads")
    p.add_argument("--out", default=None, help="output folder (default: out/NAME)")
    p.add_argument("--duration", type=float, default=None, help="override the forward run's duration (s)")
    p.add_argument("--json", action="store_true", help="print the JSON summary")
    _add_set(p)
    p.set_defaults(func=_cmd_inverse, native=True)

    p = sub.add_parser("capacity", help="dynamic load carrying capacity (DLCC) of each resolution, LP bound",
                       description=("Largest object mass (scaled at constant geometry; with --payload or the "
                                    "scenario's inverse.payload also a point payload) each resolution carries along "
                                    "SCENARIO's trajectory within the motor torque-speed lines (eq. 36), in closed "
                                    "form; the LP bound over all distributions; energy weights that maximise it. "
                                    "Writes DIR/capacity.mcap, plots and capacity.json."))
    p.add_argument("scenario", help="scenario YAML file")
    p.add_argument("--payload", type=float, nargs=3, metavar=("X", "Y", "Z"), default=None,
                   help="point payload position in the object frame, m")
    p.add_argument("--no-lp", action="store_true", help="skip the LP bound")
    p.add_argument("--no-optimise", action="store_true", help="skip the weight optimisation")
    p.add_argument("--check", action="store_true",
                   help="brute-force check: rerun the inverse dynamics at (1 -/+ 1e-6) x each capacity; exit 1 if off")
    p.add_argument("--out", default=None, help="output folder (default: out/NAME)")
    p.add_argument("--duration", type=float, default=None, help="override the forward run's duration (s)")
    p.add_argument("--json", action="store_true", help="print the JSON summary")
    _add_set(p)
    p.set_defaults(func=_cmd_capacity, native=True)

    p = sub.add_parser("optimize", help="payload-optimal motion: retime the scenario's object path (--retime), "
                                        "free the path (--path)",
                       description=("Keep SCENARIO's object path (inverse.object_motion's waypoints) and free its time "
                                    "law, rest to rest: for each linear resolution and the LP bound the heaviest "
                                    "load carried within T_MAX (default: the scenario's duration) by the motor lines "
                                    "of eq. 36, the minimum time of the bare object (or of --payload), the "
                                    "payload-time curve. Writes DIR/NAME_retimed.yaml (the scenario with a sampled "
                                    "time law, for run/inverse/capacity), optimize.mcap, plots and optimize.json. "
                                    "With --path the object path itself is free: a B-spline between the first and "
                                    "last waypoint poses (inverse.optimize: control_points, starts, seed, "
                                    "manipulability_margin, sample_dt) optimised for --method under the scenario's "
                                    "time law, then with its time law free within T_MAX; writes DIR/NAME_path.yaml "
                                    "(two waypoints, the path, the sampled law)."))
    p.add_argument("scenario", help="scenario YAML file")
    p.add_argument("--retime", action="store_true", help="fixed path, free timing")
    p.add_argument("--path", action="store_true",
                   help="free path: a B-spline between the first and last waypoint poses (inverse.optimize), "
                        "optimised with its time law for --method; writes DIR/NAME_path.yaml")
    p.add_argument("--weights", action="store_true",
                   help="with --method min_energy: optimise the energy weights with the time law (--retime) and "
                        "with the path (--path); the written scenarios carry them")
    p.add_argument("--payload", type=float, default=None, metavar="KG",
                   help="also the minimum time of this carried mass (kg; the payload's, or the object's without "
                        "inverse.payload)")
    p.add_argument("--duration", type=float, default=None, metavar="T_MAX",
                   help="the duration bound (s; default: the object motion's)")
    p.add_argument("--method", choices=LINEAR_METHODS_CLI + ("lp",), default="min_energy",
                   help="the resolution whose time law the optimised scenario carries, and whose path --path "
                        "optimises (default min_energy)")
    p.add_argument("--intervals", type=int, default=50, help="grid intervals per waypoint segment (default 50)")
    p.add_argument("--replay", action="store_true",
                   help="replay the optimum's torques open loop, native and MuJoCo twin, against the scenario's "
                        "thresholds: with --retime the retimed law (optimize.json 'replay', DIR/optimum_run.mcap), "
                        "with --path the free path (its 'replay', DIR/optimum_path_run.mcap), run logs for "
                        "coopsim animate")
    p.add_argument("--closed-loop", action="store_true",
                   help="with --replay: also replay under feedback with the optimum as feedforward: the scenario's "
                        "computed_torque law about the optimised object motion where it has one (square arms), "
                        "else joint PD about the optimised joint path (replay 'closed_loop': the law, tracking "
                        "error, feedback share, motor lines); done without asking where the open loop leaves the "
                        "thresholds or the scenario has a control: section")
    p.add_argument("--out", default=None, help="output folder (default: out/NAME/optimize)")
    p.add_argument("--json", action="store_true", help="print the JSON summary")
    _add_set(p)
    p.set_defaults(func=_cmd_optimize, native=True)

    p = sub.add_parser("sweep", help="parameter sweep of one study over a grid or a quasi-random design (Dask)",
                       description=("Run SWEEP (YAML: a base scenario, axes of --set paths, a study: simulate, "
                                    "validate, inverse or capacity) at every point, on an embedded Dask "
                                    "LocalCluster (one worker process per core), an existing cluster "
                                    "(--scheduler) or serially; checkpoint each point in DIR/points.jsonl as it "
                                    "finishes; write results.parquet, results.csv, sweep.json, sweep.mcap and "
                                    "plots into DIR."))
    p.add_argument("sweep", help="sweep YAML file")
    p.add_argument("--out", default=None, help="output folder (default: out/NAME)")
    p.add_argument("--serial", action="store_true", help="run the points in this process, one after another")
    p.add_argument("--workers", type=int, default=None,
                   help="worker processes of the embedded cluster (default: cores)")
    p.add_argument("--scheduler", default=None, metavar="ADDRESS",
                   help="run on the Dask cluster whose scheduler is at ADDRESS (e.g. tcp://10.0.0.5:8786)")
    p.add_argument("--resume", action="store_true",
                   help="keep the finished points of DIR/points.jsonl (the same sweep) and run only the others")
    p.add_argument("--json", action="store_true", help="print sweep.json")
    _add_set(p)
    p.set_defaults(func=_cmd_sweep, native=True)

    p = sub.add_parser("bench", help="work-precision benchmark: native model against MuJoCo and Pinocchio",
                       description=("Time the native model (DOP853/DOPRI5 tolerance and RK4 step ladders), the MuJoCo "
                                    "twin (RK4/Euler/implicitfast step ladders) and, with the optional 'pin' package, "
                                    "Pinocchio's constraintDynamics against a tight native reference; µs per dynamics "
                                    "evaluation, scaling in arms and joints, start-up times. Writes bench.json, "
                                    "bench.md, runs.csv, scaling.csv and plots into DIR."))
    p.add_argument("scenarios", nargs="*", help="scenario YAML files (default: scenarios/*.yaml)")
    p.add_argument("--out", default="out/bench", help="output folder (default: out/bench)")
    p.add_argument("--quick", action="store_true", help="short runs and ladders, no start-up timing (tests, CI)")
    p.add_argument("--json", action="store_true", help="print bench.json to stdout")
    p.set_defaults(func=_cmd_bench, native=True)

    p = sub.add_parser("animate", help="render a run (both models overlaid) into a GIF or MP4",
                       description=("Render SOURCE with MuJoCo's offscreen renderer: the native model (blue, with "
                                    "the object and grasp frames) and the MuJoCo twin over it (a translucent "
                                    "sleeve), a time stamp and the two models' joint-angle difference. SOURCE is "
                                    "a `coopsim run` log (LOG.mcap; the geometry comes from the scenario file it "
                                    "names) or a scenario (its log out/NAME/NAME.mcap when written from the same "
                                    "file, else both models are run). Headless: MUJOCO_GL=egl (package libegl1) "
                                    "or osmesa (libosmesa6); EGL is used by default without a display."))
    p.add_argument("source", help="scenario YAML file or LOG.mcap")
    p.add_argument("--out", default=None,
                   help="FILE.gif (Pillow) or FILE.mp4 (needs ffmpeg on PATH); default: NAME.gif in out/NAME/ "
                        "(scenario) or beside the log")
    p.add_argument("--scenario", default=None, help="with a LOG.mcap: the scenario file to draw it with")
    p.add_argument("--closed-loop", action="store_true",
                   help="with the run log of `coopsim optimize --replay` (optimum_run.mcap): draw its closed-loop "
                        "replay (the /closed_loop/ topics) in place of the open loop")
    p.add_argument("--fps", type=float, default=20.0, help="frames per second of the video (default: 20)")
    p.add_argument("--speed", type=float, default=1.0,
                   help="simulated seconds per second of video (default: 1, real time)")
    p.add_argument("--duration", type=float, default=None,
                   help="simulated seconds to show from t = 0 (default: the whole run; frames: "
                        "floor(duration x fps / speed) + 1)")
    p.add_argument("--width", type=int, default=480, help="frame width in pixels (default: 480)")
    p.add_argument("--height", type=int, default=360, help="frame height in pixels (default: 360)")
    p.add_argument("--json", action="store_true", help="print what was written as JSON")
    _add_set(p)
    p.set_defaults(func=_cmd_animate)

    p = sub.add_parser("view", help="open MuJoCo's interactive viewer at the consistent initial state",
                       description=("Open MuJoCo's interactive viewer on SOURCE (a scenario YAML file or a twin "
                                    "models/NAME.xml) at the consistent initial state of `coopsim run` (the "
                                    "keyframe); needs a display."))
    p.add_argument("source", help="scenario YAML file or MJCF file")
    _add_set(p)
    p.set_defaults(func=_cmd_view)
    return parser


COMPILE_NOTICES = {      # what a first run compiles, by compile group (`coopsim.compiled.api`)
    "base": "the native model for this machine (first run only; about 20 s)",
    "extras": "inverse kinematics and the capacity objective (first use only; a few seconds)",
    "control": "the controllers for this machine (first closed-loop run only; about 20 s)",
}


def _announce_compile() -> None:
    """Say so when a first run on this machine starts compiling part of the native model, and compile
    it on all cores (`coopsim.apps.warmup`)."""
    from coopsim.compiled.api import set_compile_notice

    def notice(group):
        def say():
            print(f"coopsim: compiling {COMPILE_NOTICES[group]}...", file=sys.stderr, flush=True)
            from coopsim.apps.warmup import warm_up_group

            warm_up_group(group)
        return say

    set_compile_notice(**{group: notice(group) for group in COMPILE_NOTICES})


INTERRUPTED = 130   # the shell's status for a command stopped by Ctrl-C (128 + SIGINT)


class Stopped(KeyboardInterrupt):
    """A stop signal (SIGTERM: what `timeout`, systemd, Slurm and `docker stop` send), raised in the main
    thread as Ctrl-C's KeyboardInterrupt is, so that it takes the same way out (no partial set, the
    workers stopped).

    Args:
        signum: the signal's number.

    Attributes:
        signum: the signal's number; the command's exit status is 128 + signum.
    """

    def __init__(self, signum: int):
        super().__init__(signum)
        self.signum = signum


def _stop(signum: int, frame) -> None:
    """SIGTERM's handler: raise `Stopped` once; a repeated SIGTERM is ignored while the command cleans up."""
    signal.signal(signum, signal.SIG_IGN)
    raise Stopped(signum)


def _stopped(exc: KeyboardInterrupt) -> int:
    """Say on stderr, in one line, that the command was interrupted (Ctrl-C) or stopped (`Stopped`), and
    return its exit status, 128 + the signal's number."""
    if isinstance(exc, Stopped):
        print(f"coopsim: stopped by {signal.Signals(exc.signum).name}", file=sys.stderr)
        return 128 + exc.signum
    print("coopsim: interrupted", file=sys.stderr)
    return INTERRUPTED


def main(argv: list[str] | None = None) -> int:
    """Run one command and return its exit status. `coopsim` alone prints the help.

    A CoopsimError or OSError prints one line `coopsim: error: …` on stderr (status 2); a closed stdout
    pipe ends quietly (status 1); Ctrl-C (or a `Stopped`) prints one line and leaves no partial set.

    Args:
        argv: the command-line arguments after the program name; None: sys.argv[1:].

    Returns:
        int: 0, 1 (a check failed), 2 (bad input or a failure with a one-line reason), 130 (interrupted),
            128 + the signal's number (stopped by a signal, `Stopped`).
    """
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.command is None:
        parser.print_help()
        return 0
    if getattr(args, "native", False):
        _announce_compile()
    with warnings.catch_warnings():
        warnings.simplefilter("default")
        try:
            status = args.func(args)
            sys.stdout.flush()   # a closed pipe shows here, not in the interpreter's exit
            return status
        except (CoopsimError, OSError) as exc:
            if isinstance(exc, BrokenPipeError):
                return _closed_pipe()
            one_line = " ".join(part.strip() for part in str(exc).splitlines())
            print(f"coopsim: error: {one_line}", file=sys.stderr)
            return 2
        except KeyboardInterrupt as exc:
            return _stopped(exc)


def _closed_pipe() -> int:
    """The reader of stdout went away (e.g. `coopsim ... | head`): stop quietly, as Python's docs advise
    (point stdout at /dev/null so the interpreter's final flush does not fail again)."""
    import os

    os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
    return 1


def console_main() -> None:
    """The `coopsim` console command (and `python -m coopsim.cli`): `main`, then leave at once.

    Python's own shutdown is slow once the compiled kernels are loaded (numba's and LLVM's modules,
    every module's cleanup) and does nothing a finished command needs: its outputs are
    written, closed and renamed into place, its figure workers and clusters are joined. So after main
    returns, stdout and stderr are flushed and the process ends with os._exit(status). An exception
    that escapes main takes the normal way out (traceback, full shutdown). SIGTERM stops the command as
    Ctrl-C does (`Stopped`: one line, no partial set, the workers stopped; status 143)."""
    import os

    signal.signal(signal.SIGTERM, _stop)
    try:
        status = main()
    except KeyboardInterrupt as exc:   # before main's own handling (while the arguments are read)
        status = _stopped(exc)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)   # the command has ended: it leaves at once
    try:
        sys.stdout.flush()
    except BrokenPipeError:
        status = _closed_pipe()
    sys.stderr.flush()
    os._exit(status)


if __name__ == "__main__":
    console_main()
