"""numba's call-type resolution, remembered while coopsim's functions compile: each operation's
signature is worked out once per process.

To type `a * b` on two float64, or `A[i, j]`, numba's `BaseFunction.get_call_type` tries every
template registered for the operator, in order, catching the failures, until one accepts the
argument types; lowering asks again for each call it lowers. The kernels hold thousands of such calls
over a few hundred distinct (function, argument types) pairs, so most resolutions repeat one made
before.

`install()` wraps `get_call_type` with a table keyed by the function type, typing context, argument
types, keyword types and the compilation flags in force (an overload compiles its implementation per
set of flags: numba's own `_OverloadFunctionTemplate` keys its cache on them too). A hit returns the
signature found before and records the implementation it chose, as the first resolution did; only
successful resolutions are kept, so a failure is always worked out (and reported) by numba. A type
numba extends later (a new overload registered) is a new function type object, hence a new key.

The table is used only while a coopsim function compiles: the pipelines of `jit.kernel` and
`jit.entry` (`CoopsimCompile`) count, per thread, the coopsim compiles in progress, and what numba
compiles for them meanwhile (their callees, the implementations of the operations they use) is in
that scope too. Outside it (a user's `@njit` code compiled on its own) `get_call_type` is numba's,
and the table is neither read nor filled. It installs nothing on a numba outside
`numba_range.NUMBA_RANGE` or without the method (numba then resolves as usual).
"""

from __future__ import annotations

from numba.core import targetconfig
from numba.core.types import functions

from coopsim.compiled.toolchain.numba_range import supported_numba
from coopsim.compiled.toolchain.scope import ThreadScope

_MEMO: dict = {}
_FLAGS: dict = {}     # id(flags) → (flags, a hashable summary of their values)
coopsim_compile = ThreadScope()   # `with coopsim_compile():` the scope of a coopsim function's compile


def in_coopsim_compile() -> bool:
    """Whether a coopsim function is being compiled on this thread.

    Returns:
        bool: True inside a `coopsim_compile` scope.
    """
    return coopsim_compile.active


class CoopsimCompile:
    """Mixin for a numba compiler pipeline (a `compiler.CompilerBase` subclass, listed before it): its
    whole run is a coopsim compile (`coopsim_compile`)."""

    def _compile_core(self):
        with coopsim_compile():
            return super()._compile_core()


def _flags_key(flags):
    """A hashable summary of numba's compilation `flags` (None outside a compilation), made once per
    flags object (hashing numba's Flags compares every option on each use)."""
    if flags is None:
        return None
    hit = _FLAGS.get(id(flags))
    if hit is None or hit[0] is not flags:
        hit = _FLAGS[id(flags)] = (flags, repr(sorted(flags.values().items(), key=lambda item: item[0])))
    return hit[1]


def install() -> bool:
    """Wrap `BaseFunction.get_call_type` (module docstring); idempotent.

    Returns:
        bool: True if installed (now or before); False, nothing installed, on a numba outside
        `numba_range.NUMBA_RANGE` or without the wrapped methods.
    """
    base = functions.BaseFunction
    if not (supported_numba() and hasattr(base, "get_call_type")
            and hasattr(targetconfig.ConfigStack, "top_or_none")):
        return False
    if getattr(base.get_call_type, "_coopsim", False):
        return True
    get_call_type = base.get_call_type

    def remembered(self, context, args, kws):
        if not coopsim_compile.active:    # not compiling a coopsim function: numba's own
            return get_call_type(self, context, args, kws)
        key = (self, context, tuple(args), tuple(kws.items()) if kws else (),
               _flags_key(targetconfig.ConfigStack.top_or_none()))
        try:
            hit = _MEMO.get(key)
        except TypeError:                # an unhashable argument type: resolve as numba does
            return get_call_type(self, context, args, kws)
        if hit is not None:
            sig, impl_key = hit
            self._impl_keys[sig.args] = impl_key
            return sig
        sig = get_call_type(self, context, args, kws)
        if sig is not None:
            _MEMO[key] = (sig, self._impl_keys[sig.args])
        return sig

    remembered._coopsim = True
    remembered.__wrapped__ = get_call_type
    base.get_call_type = remembered
    return True
