"""How numba compiles coopsim's kernels: the two compilation modes (`jit`) and the wrappers that make
the first compile fast (`linking`, `resolution`, `loading`), which act on coopsim's functions only and
only on the numba versions they follow (`numba_range`); `scope` is the per-thread state that keeps
them to coopsim's compiles. The stages never import anything here but
`jit`."""
