"""The applications the commands run, built on the layers below: animation, the benchmark, sweeps,
the first compile, progress bars.

    animate/         a run rendered by MuJoCo's offscreen renderer → GIF/MP4; the interactive viewer
    bench/           the work-precision benchmark against MuJoCo and Pinocchio, start-up and commands,
                     and its report (JSON, CSV, Markdown, figures)
    sweep.py         the sweep file, its points, one point's study (pure)
    sweep_run.py     sweeps run serially or on Dask, checkpoint and resume, results table, summary, MCAP
    warmup.py        the first compile of the native model, on two cores, no kernel compiled twice
    progress.py      progress bars on a terminal
"""
