"""Figures (PNG, matplotlib's Agg canvas), drawn from logs and results, never from a live engine.

    figure.py   what every figure shares: the panel grid with room for legends, legends, log axes
    run.py      a run's comparison plots, native model against MuJoCo twin (Figs. 4–5)
    control.py  tracking errors of a closed-loop run
    inverse.py  inverse dynamics and capacity figures
    optimize.py the retiming's phase plane, motors against their lines before/after, payload–time curve
    free_path.py  the object's path before and after `coopsim optimize --path`
    sweep.py    sweep line plots, heat maps with the saturating motor marked, histograms
    bench.py    the work-precision benchmark's figures
    render.py   figure output on worker processes started with each command, fixed margins
"""
