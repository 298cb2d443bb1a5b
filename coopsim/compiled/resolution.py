"""numba's call-type resolution, remembered: each operation's signature is worked out once per process.

To type `a * b` on two float64, or `A[i, j]`, numba's `BaseFunction.get_call_type` tries every
template registered for the operator, in order, catching the failures, until one accepts the
argument types; lowering asks again for each call it lowers. The kernels hold thousands of such calls
over a few hundred distinct (function, argument types) pairs, and the repeats were about a sixth of
the first compile (4.2 of 26 s on the paper scene's time loop; 0.7 s once remembered).

`install()` wraps `get_call_type` with a table keyed by the function type, typing context, argument
types, keyword types and the compilation flags in force (an overload compiles its implementation per
set of flags: numba's own `_OverloadFunctionTemplate` keys its cache on them too). A hit returns the
signature found before and records the implementation it chose, as the first resolution did; only
successful resolutions are kept, so a failure is always worked out (and reported) by numba. A type
numba extends later (a new overload registered) is a new function type object, hence a new key.
It installs nothing on a numba outside `linking.NUMBA_RANGE` or without the method (numba then
resolves as usual).
"""

from __future__ import annotations

from numba.core import targetconfig
from numba.core.types import functions

_MEMO: dict = {}
_FLAGS: dict = {}     # id(flags) → (flags, a hashable summary of their values)


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
    """Wrap `BaseFunction.get_call_type` (module docstring); True if installed (idempotent)."""
    from .linking import supported_numba

    base = functions.BaseFunction
    if not (supported_numba() and hasattr(base, "get_call_type")
            and hasattr(targetconfig.ConfigStack, "top_or_none")):
        return False
    if getattr(base.get_call_type, "_coopsim", False):
        return True
    get_call_type = base.get_call_type

    def remembered(self, context, args, kws):
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
