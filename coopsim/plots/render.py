"""Figure output: PNG files drawn by matplotlib's Agg canvas on worker processes.

matplotlib draws on one thread and costs about a second to import and half a second to a second per
figure, so the commands draw on worker processes (two, forked, where the platform forks and has two
cores). `FigureWorkers` starts them at the beginning of a command: while the command computes on one
core, they import matplotlib and draw a throw-away figure (font cache, mathtext parser) at a lower
priority on the other; the command's figures are then drawn on both. A job is (builder, args, path):
the worker writes save_figure(builder(*args), path). Builders and their arguments travel by pickle,
so builders are module-level functions. This module does not import matplotlib itself.
The workers leave SIGINT and SIGTERM to the command, which stops them, and end with it however it ends
(`coopsim.io.processes`: killed, too)."""

from __future__ import annotations

import io
import multiprocessing
import os
import signal
import threading
from concurrent.futures import ProcessPoolExecutor, ThreadPoolExecutor
from pathlib import Path
from typing import TYPE_CHECKING, Callable, TypeVar

from coopsim.io.atomic import atomic_path
from coopsim.io.processes import end_with_parent

if TYPE_CHECKING:
    from matplotlib.figure import Figure

T = TypeVar("T")
DPI = 110
PNG_COMPRESSION = 1   # zlib level: faster per figure than the default 6, for slightly larger files
WORKER_NICENESS = 19   # the workers yield the CPU to the command while it computes
# Margins and gaps (inches) around a grid of axes with 10-point tick labels, axis labels and titles of
# up to two lines: matplotlib's tight_layout finds them by drawing every text once more (about half
# a second a figure), so the figures here use these instead.
MARGIN = {"left": 0.85, "right": 0.2, "bottom": 0.55, "top": 0.5, "suptitle": 0.35, "wgap": 0.85, "hgap": 0.85}


def fixed_layout(fig: Figure) -> None:
    """Place fig's grid of subplots with the MARGIN gaps (inches), whatever the figure size.

    Args:
        fig: the figure, its subplot parameters set.
    """
    specs = [ax.get_subplotspec() for ax in fig.axes if ax.get_subplotspec() is not None]
    if not specs:
        return
    rows, cols = specs[0].get_gridspec().get_geometry()
    W, H = fig.get_size_inches()
    top = MARGIN["top"] + (MARGIN["suptitle"] if fig.get_suptitle() else 0.0)
    left, right, bottom = MARGIN["left"] / W, 1.0 - MARGIN["right"] / W, MARGIN["bottom"] / H
    width = (W * (right - left) - MARGIN["wgap"] * (cols - 1)) / cols
    height = (H * (1.0 - top / H - bottom) - MARGIN["hgap"] * (rows - 1)) / rows
    fig.subplots_adjust(left=left, right=right, bottom=bottom, top=1.0 - top / H,
                        wspace=MARGIN["wgap"] / width, hspace=MARGIN["hgap"] / height)


def _draw_png(fig: Figure, target) -> None:
    """Lay out (`fixed_layout`) and draw `fig` as PNG (DPI dots per inch, zlib level PNG_COMPRESSION) into
    `target` (a path or a file)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    FigureCanvasAgg(fig)
    fixed_layout(fig)
    fig.savefig(target, format="png", dpi=DPI, pil_kwargs={"compress_level": PNG_COMPRESSION})


def save_figure(fig: Figure, path: Path) -> Path:
    """Write `fig` as PNG atomically (`_draw_png`: laid out by `fixed_layout`, DPI dots per inch).

    Args:
        fig: the figure.
        path: the PNG file (its folder is created if missing).

    Returns:
        Path: the path written.
    """
    with atomic_path(path) as tmp:
        _draw_png(fig, tmp)
    return path


def _start_worker(parent: int, kernel: bool, warm: bool) -> None:
    """Worker initializer: ignore SIGINT and SIGTERM (a Ctrl-C or a stop reaches the whole process group;
    the command stops its workers itself), end with the command (`end_with_parent`, its process id
    `parent`; `kernel`: the workers were started on its main thread) and, with `warm`, warm up
    (`_warm_up`)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    end_with_parent(parent, kernel=kernel)
    if warm:
        _warm_up()


def _warm_up() -> None:
    """Lower the priority, import matplotlib and draw a small figure with a log axis and a legend into
    memory (what a worker would otherwise do on its first job)."""
    os.nice(WORKER_NICENESS)
    from matplotlib.figure import Figure

    fig = Figure(figsize=(2, 2))
    ax = fig.subplots()
    ax.semilogy([0.0, 1.0], [1e-9, 1e-3], label="x")
    ax.set(title="t", xlabel="x", ylabel="y")
    ax.legend()
    _draw_png(fig, io.BytesIO())


def _render(job) -> str:
    fn, args, path = job
    return str(save_figure(fn(*args), Path(path)))


def _can_fork(n: int) -> bool:
    return n >= 2 and (os.cpu_count() or 1) >= 2 and "fork" in multiprocessing.get_all_start_methods()


class FigureWorkers:
    """Worker processes for figures (module docstring), started by the constructor.

    Without fork or a second core (or with n < 2) there are none and `render` draws in this process. Use
    as a context manager (an exception in the block stops the workers at once), or call `close`.

    Args:
        n: the number of worker processes.
        warm: warm the workers up as they start (import matplotlib, draw a throw-away figure).

    Attributes:
        pool: the worker processes (a ProcessPoolExecutor), None when there are none or after `close`.
    """

    def __init__(self, n: int = 2, warm: bool = True):
        self.pool = None
        if _can_fork(n):
            on_main = threading.current_thread() is threading.main_thread()
            self.pool = ProcessPoolExecutor(n, mp_context=multiprocessing.get_context("fork"),
                                            initializer=_start_worker, initargs=(os.getpid(), on_main, warm))
            self.pool.submit(int)   # a fork-context pool starts all its workers at the first submit

    def render(self, jobs: list, first: tuple[int, ...] = ()) -> list[Path]:
        """Write every job's figure.

        The jobs numbered in `first` (the costliest) are handed out before the others, so that the
        workers finish together. A builder's error is raised here.

        Args:
            jobs: (builder, args, path) each: the figure builder(*args) is written to path as PNG.
            first: indices (0-based) of the jobs handed out first.

        Returns:
            list[Path]: the paths written, in job order.
        """
        if self.pool is None or len(jobs) < 2:
            return [Path(_render(job)) for job in jobs]
        order = [i for i in first if i < len(jobs)] + [i for i in range(len(jobs)) if i not in first]
        done = {i: self.pool.submit(_render, jobs[i]) for i in order}
        return [Path(done[i].result()) for i in range(len(jobs))]

    def close(self, stop: bool = False) -> None:
        """Shut the workers down: after their jobs, or (stop) at once, e.g. when the command failed.

        Args:
            stop: terminate the workers at once, cancelling the jobs not started.
        """
        if self.pool is None:
            return
        if stop:   # SIGKILL: the workers ignore SIGTERM
            for proc in list(getattr(self.pool, "_processes", {}).values()):
                proc.kill()
        self.pool.shutdown(wait=True, cancel_futures=True)
        self.pool = None

    def __enter__(self) -> FigureWorkers:
        return self

    def __exit__(self, exc_type, *exc) -> None:
        self.close(stop=exc_type is not None)


def render_while(draw: Callable[[], list[Path]], work: Callable[[], T]) -> tuple[list[Path], T]:
    """Run `draw` on a thread of this process while `work` runs here, so the workers draw meanwhile.

    An error of either is raised here once both have ended.

    Args:
        draw: a call that hands its figure jobs to FigureWorkers and waits for them.
        work: the work done meanwhile (e.g. writing the log).

    Returns:
        tuple[list[Path], T]: (draw(), work()).
    """
    with ThreadPoolExecutor(1) as thread:
        figures = thread.submit(draw)
        done = work()
        return figures.result(), done


def render_figures(jobs: list, workers: FigureWorkers | None = None, first: tuple[int, ...] = ()) -> list[Path]:
    """Write the figures of `jobs` on `workers`, the jobs numbered in `first` handed out first.

    Args:
        jobs: (builder, args, path) each, as `FigureWorkers.render` takes them.
        workers: the workers; None: workers started (not warmed) for this call only.
        first: indices (0-based) of the jobs handed out first.

    Returns:
        list[Path]: the paths written, in job order.
    """
    if workers is not None:
        return workers.render(jobs, first)
    with FigureWorkers(min(2, len(jobs)), warm=False) as own:
        return own.render(jobs, first)
