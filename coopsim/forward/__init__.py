"""Forward simulation: the scenario's torques through an engine, sampled, with run diagnostics.

    simulate.py     the pipeline: consistent initial state, the time loop, every reported quantity
    engines.py      the engines behind one interface (project, run, sample): compiled, reference, stages
    diagnostics.py  run warnings (ill-conditioned chain, arm singularities, large corrections, RK4 steps)
"""
