"""The two compilation modes of the package (numba, cached on disk next to the sources).

`kernel`: an internal compiled function, callable from compiled code only. Skipping numba's
CPython and C wrappers, which must box and unbox every field of the model and workspace tuples,
shortens the compile; so do compiling it to LLVM IR only, linked into the entries that call it
(`linking`), and remembering how each operation's call type resolves (`resolution`); code loaded
from the cache skips numba's compiler registries (`loading`). Kernels let
LLVM contract a·b + c into fused multiply-adds (one rounding instead of two: results differ from the
NumPy reference in the last bits only).
`entry`: a compiled function called from Python (batch evaluations, the time loop, sampling); it
releases the GIL, so batches run on threads.

`linking`, `resolution` and `loading` change numba's behaviour for coopsim's functions only: those
decorated here (marked with `loading.MARK`; compiled by the pipelines `linking.KernelCompiler` and
`EntryCompiler`, which mark a coopsim compile in progress) and, for `loading`, the package's other
cached functions (the records' constructors, plain `njit`). numba compiles, caches and loads a user's
own `@njit` code in the same process as it does without coopsim (code of a user's that calls a
kernel has coopsim's code linked into it: `linking`).

With the environment variable COOPSIM_STOCK_NUMBA=1 none of the three is installed: numba compiles
coopsim's functions as it does by default (a slower first compile, the same code), and caches them
in a folder of their own (`stock-numba`, under the cache folder they would use otherwise), since the
other mode's cache holds kernels in a form stock numba cannot load.
"""

import inspect
import os

from numba import njit
from numba.core import compiler, config

from coopsim.compiled.toolchain import linking
from coopsim.compiled.toolchain import loading
from coopsim.compiled.toolchain import resolution

STOCK = os.environ.get("COOPSIM_STOCK_NUMBA", "") not in ("", "0")   # install none of the patches


class EntryCompiler(resolution.CoopsimCompile, compiler.Compiler):
    """numba's default pipeline; a coopsim compile (`resolution.CoopsimCompile`)."""


if STOCK:
    _kernel_pipeline = _entry_pipeline = None
else:
    _remembered = resolution.install()
    loading.install()
    _entry_pipeline = EntryCompiler if _remembered else None
    _kernel_pipeline = linking.KernelCompiler if linking.install() else _entry_pipeline


def _stock_cache_dir(py_func) -> str:
    """Where numba caches `py_func` with COOPSIM_STOCK_NUMBA set: a `stock-numba` folder under the
    cache folder it would use otherwise (NUMBA_CACHE_DIR or the one the package sets, else the
    source's __pycache__)."""
    base = config.CACHE_DIR or os.path.join(os.path.dirname(os.path.abspath(inspect.getfile(py_func))),
                                            "__pycache__")
    return os.path.join(base, "stock-numba")


def _mode(pipeline_class, **options):
    """A decorator compiling a function with numba's `njit(cache=True, **options)` and
    `pipeline_class` (none: numba's default), the function marked as coopsim's (`loading.MARK`)."""
    if pipeline_class is not None:
        options["pipeline_class"] = pipeline_class
    jit = njit(cache=True, **options)

    def decorate(py_func):
        setattr(py_func, loading.MARK, True)
        if not STOCK:
            return jit(py_func)
        previous = config.CACHE_DIR
        config.CACHE_DIR = _stock_cache_dir(py_func)   # numba picks a function's cache folder here
        try:
            return jit(py_func)
        finally:
            config.CACHE_DIR = previous

    return decorate


kernel = _mode(_kernel_pipeline, no_cpython_wrapper=True, no_cfunc_wrapper=True, error_model="numpy",
               fastmath={"contract"})
entry = _mode(_entry_pipeline, nogil=True, error_model="numpy")
