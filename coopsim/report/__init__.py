"""Reports of results as text and JSON: the PASS table and `summary.json` of a run, and the inverse
and capacity study's summary, series and checks.

    summary.py         a run's summary (agreement, warnings, settings)
    inverse_report.py  the inverse-dynamics and capacity study: what `coopsim inverse` and
                       `coopsim capacity` report and log
    optimize_report.py the retiming study of `coopsim optimize --retime`: the fixed path's time law
                       freed, summary, series and the optimised scenario
    path_report.py     the free-path study: what `coopsim optimize --path` reports and logs
    optimum_replay.py  the optimum (retimed or free path) replayed open loop, native and MuJoCo twin
                       (`coopsim optimize --replay`): agreement and run log
    closed_replay.py   the optimum replayed under feedback about its joint path, the optimum as
                       feedforward (open loop outside the thresholds, a control: section, --closed-loop)
"""
