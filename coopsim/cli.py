"""Command-line interface: thin dispatch over the library (`coopsim --help`)."""

from __future__ import annotations

import argparse
import json
import sys
import warnings

from .model import CoopsimError


def _cmd_simulate(args) -> int:
    from .scenario import load_scenario
    from .simulate import simulate
    from .summary import format_simulation_summary, simulation_summary

    model = load_scenario(args.scenario)
    summary = simulation_summary(simulate(model, duration=args.duration))
    print(json.dumps(summary, indent=2) if args.json else format_simulation_summary(summary))
    return 0


def _cmd_mjcf(args) -> int:
    from pathlib import Path

    from .atomic import write_text_atomic
    from .mjcf import mjcf_text
    from .scenario import load_scenario

    for scenario in _scenario_paths(args.scenarios):
        path = Path(args.out) / f"{Path(scenario).stem}.xml"
        write_text_atomic(path, mjcf_text(load_scenario(scenario), _display_path(scenario)))
        print(path)
    return 0


def _cmd_validate(args) -> int:
    from .compare import format_comparison
    from .harness import cross_validate
    from .progress import ProgressBar
    from .scenario import load_scenario

    results = []
    for scenario in _scenario_paths(args.scenarios):
        bar = ProgressBar()
        cv = cross_validate(load_scenario(scenario), duration=args.duration, progress=bar)
        bar.close()
        results.append(cv.comparison)
        if not args.json:
            print(format_comparison(cv.comparison))
            for failure in cv.comparison.failures():
                print(f"  FAIL: {failure}")
    ok = all(c.passed for c in results)
    if args.json:
        print(json.dumps({"passed": ok, "scenarios": [c.as_dict() for c in results]}, indent=2))
    else:
        print(f"cross-validation: {sum(c.passed for c in results)}/{len(results)} scenarios agree")
    return 0 if ok else 1


def _scenario_paths(given: list[str]) -> list[str]:
    """The given scenario files, or every bundled `scenarios/*.yaml` when none is given."""
    from pathlib import Path

    if given:
        return given
    found = sorted(str(p) for p in Path("scenarios").glob("*.yaml"))
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


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="coopsim", description=(
        "Cooperative manipulators: recursive Gibbs-Appell closed-chain dynamics, validated against MuJoCo."))
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("simulate", help="forward-simulate a scenario with the native model and print a summary",
                       description="Forward-simulate SCENARIO (YAML) with the native closed-chain model.")
    p.add_argument("scenario", help="scenario YAML file")
    p.add_argument("--duration", type=float, default=None, help="override the scenario's duration (s)")
    p.add_argument("--json", action="store_true", help="print a machine-readable JSON summary")
    p.set_defaults(func=_cmd_simulate)

    p = sub.add_parser("validate", help="cross-validate scenarios against their MuJoCo twins",
                       description=("Run the native model and the MuJoCo twin of each SCENARIO (default: "
                                    "scenarios/*.yaml) and compare them; exit 0 only if all agree."))
    p.add_argument("scenarios", nargs="*", help="scenario YAML files")
    p.add_argument("--duration", type=float, default=None, help="override the scenarios' duration (s)")
    p.add_argument("--json", action="store_true", help="print a machine-readable JSON table")
    p.set_defaults(func=_cmd_validate)

    p = sub.add_parser("mjcf", help="write the MuJoCo twin of scenarios as MJCF (models/NAME.xml)",
                       description="Write the MuJoCo twin (MJCF) of each SCENARIO (default: scenarios/*.yaml).")
    p.add_argument("scenarios", nargs="*", help="scenario YAML files")
    p.add_argument("--out", default="models", help="output folder (default: models)")
    p.set_defaults(func=_cmd_mjcf)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    with warnings.catch_warnings():
        warnings.simplefilter("default")
        try:
            return args.func(args)
        except CoopsimError as exc:
            print(f"coopsim: error: {exc}", file=sys.stderr)
            return 2


if __name__ == "__main__":
    sys.exit(main())
