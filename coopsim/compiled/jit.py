"""The two compilation modes of the package (numba, cached on disk next to the sources).

`kernel`: an internal compiled function, callable from compiled code only. Skipping numba's
CPython and C wrappers, which must box and unbox every field of the model and workspace tuples,
cuts compile time by about two thirds; compiling it to LLVM IR only, linked into the entries that
call it (`linking`), and remembering how each operation's call type resolves (`resolution`), halve
what is left; code loaded from the cache skips numba's compiler registries (`loading`). Kernels let LLVM contract a·b + c into fused multiply-adds
(one rounding instead of two: results differ from the NumPy reference in the last bits only).
`entry`: a compiled function called from Python (batch evaluations, the time loop, sampling); it
releases the GIL, so batches run on threads.
"""

from numba import njit

from . import linking, loading, resolution

resolution.install()
loading.install()
_lazy = {"pipeline_class": linking.KernelCompiler} if linking.install() else {}
kernel = njit(cache=True, no_cpython_wrapper=True, no_cfunc_wrapper=True, error_model="numpy",
              fastmath={"contract"}, **_lazy)
entry = njit(cache=True, nogil=True, error_model="numpy")
