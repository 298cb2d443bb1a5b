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
