"""Compiled code of coopsim's functions loaded from numba's cache without loading numba's compiler first.

Before it loads a function from its on-disk cache, numba refreshes its target context: it imports and
installs every typing and lowering registry (numba's NumPy, math, random, typed containers…; the
linear-algebra one imports SciPy's), a noticeable part of a command's start. Loading
needs none of it: the cached object code is linked against numba's runtime (NRT) and its C helpers,
and nothing is typed or lowered. A compilation refreshes the contexts itself (numba's CompilerBase
does, before typing), so what a later compile needs is still loaded then.

`install()` wraps `Cache.load_overload` to initialise the runtime only (`rtsys.initialize`, what the
refresh does first) for the cache of a coopsim function (`is_coopsim`): one decorated by `jit.kernel`
or `jit.entry`, or defined in the coopsim package (the records' constructors, plain `njit`). Any other
function's cache (a user's `@njit(cache=True)` code) loads as numba loads it, refresh included. It
installs nothing on a numba outside `numba_range.NUMBA_RANGE` or without the methods (numba then
refreshes as usual).
"""

from __future__ import annotations

from numba.core import caching
from numba.core.runtime import rtsys

from coopsim.compiled.toolchain.numba_range import supported_numba

MARK = "_coopsim_compiled"     # the attribute `jit.kernel` and `jit.entry` set on the functions they compile


def is_coopsim(py_func) -> bool:
    """Whether `py_func` is coopsim's.

    Compiled by `jit.kernel` / `jit.entry` (marked MARK), or defined in a module of the coopsim package.

    Args:
        py_func: the Python function of a numba dispatcher (None allowed).

    Returns:
        bool: True for a coopsim function.
    """
    if getattr(py_func, MARK, False):
        return True
    module = getattr(py_func, "__module__", None) or ""
    return module == "coopsim" or module.startswith("coopsim.")


def install() -> bool:
    """Wrap `Cache.load_overload` (module docstring); idempotent.

    Returns:
        bool: True if installed (now or before); False, nothing installed, on a numba outside
        `numba_range.NUMBA_RANGE` or without the wrapped methods.
    """
    cache = caching.Cache
    if not supported_numba() or not hasattr(cache, "load_overload") or not hasattr(cache, "_load_overload"):
        return False
    if getattr(cache.load_overload, "_coopsim", False):
        return True
    numba_load_overload = cache.load_overload

    def load_overload(self, sig, target_context):
        if not is_coopsim(getattr(self, "_py_func", None)):
            return numba_load_overload(self, sig, target_context)
        rtsys.initialize(target_context)
        with self._guard_against_spurious_io_errors():
            return self._load_overload(sig, target_context)

    load_overload._coopsim = True
    load_overload.__wrapped__ = numba_load_overload
    cache.load_overload = load_overload
    return True
