"""The text table of `coopsim inverse`: fixed-width columns that never run together, and "—" (not
"nan") for what was not computed."""

from __future__ import annotations

from coopsim.report.inverse_report import METHOD_COLUMNS, format_inverse_summary


def _summary(replay: bool) -> dict:
    def method(energy, tau, stress):
        e = {"energy": energy, "energy_ratio_to_min_energy": energy / 0.5, "max_torque_norm_Nm": tau,
             "internal": {"paper": {"max_abs_component": 1.5e-17}, "nonsqueezing": {"max_abs_component": 0.061}},
             "stress": {"peak_normal_Pa": stress}, "failed_samples": []}
        if replay:
            e["replay"] = {"max_angle_error_rad": 1.9e-12}
        return e

    return {"scenario": "big", "trajectory": {"source": "forward", "start_s": 0.0, "end_s": 5.0, "samples": 501},
            "nonsqueezing": {"virtual_masses_kg": [9.42, 9.42], "centroid_offset_m": [0.0, 0.0, 0.0]},
            "bounded": {"force_bound_N": 0.12, "moment_bound_Nm": 0.03},
            "methods": {"forward": method(43940.0, 600540.246, -1.234e5), "min_energy": method(0.5, 0.25, 1513.0)},
            "energy_stress_curve": []}


def _table(text: str) -> list[list[str]]:
    lines = text.splitlines()
    start = next(i for i, ln in enumerate(lines) if ln.startswith("method"))
    return [ln.split() for ln in lines[start + 2:start + 4]]


def test_large_numbers_stay_in_their_columns():
    rows = _table(format_inverse_summary(_summary(replay=True)))
    assert rows[0] == ["forward", "4.394e+04", "87880.000", "6.005e+05", "1.5e-17", "0.061", "-1.234e+05", "1.9e-12"], rows[0]
    assert all(len(r) == 1 + len(METHOD_COLUMNS) for r in rows), rows


def test_replay_not_asked_for_is_a_dash_not_nan():
    text = format_inverse_summary(_summary(replay=False))
    rows = _table(text)
    assert [r[-1] for r in rows] == ["—", "—"], rows
    assert "nan" not in text
