"""Kernels are compiled to LLVM IR only; machine code is made once, for each entry.

numba finalizes every function it compiles on its own: it links the callees' modules into the
function's module, optimizes the whole at -O3, and emits machine code for it; then it does the same
again for every caller, whose module links the callee's. A kernel (`jit.kernel`: no CPython wrapper,
called from compiled code only) never runs on its own, so that work is thrown away: with the
closed-chain kernel's ~40 kernels nested four deep, it was about half of the first compile.

`KernelCompiler` (numba's nopython pipeline plus one pass) marks a kernel's code library *lazy*:
  - it is never finalized: its module keeps numba's per-function optimization only;
  - linked into a caller, it brings its own callees' modules with it (numba links a finalized
    library's module, which holds its callees already), definitions made `linkonce_odr` as numba does;
  - in numba's on-disk cache it is stored as that module's bitcode (kind "coopsim-ir"), not as
    object code, and loaded back lazy, so another process can link it without compiling it again.
An entry (`jit.entry`) is finalized as before: its module, with every kernel it calls linked in, is
optimized at -O3 once and becomes machine code. The code that runs is the same as numba's default
makes; only the work of compiling it changes.

numba has no public hook for this, so `install()` wraps seven methods of its code library, code
generator, CPU context and compile result. They act on coopsim's functions only; for any other
function (a user's `@njit` code in the same process) each calls numba's own method and nothing else:
  - finalizing, linking, serializing and loading a library differ only for a lazy library (or the
    cache's "coopsim-ir" kind), which only `KernelCompiler` makes;
  - making the executable of a library that links a lazy library, directly or through the libraries
    it links (an entry, or compiled code of a user's that calls a kernel), also points the
    environment globals of the kernels linked into it at their environment objects: their own
    libraries never reach the execution engine, so numba sets none of them;
  - while a lazy library's executable is made, compiled or loaded from the cache (numba's
    `get_executable` and `CompileResult._rebuild`), setting an environment global that the
    execution engine does not hold does nothing, where numba would write through a null address.
It installs nothing on a numba outside `numba_range.NUMBA_RANGE` or without these methods: kernels
are then finalized as numba does by default (slower to compile, the same code).
"""

from __future__ import annotations

import llvmlite.binding as ll
from numba.core import codegen, compiler, compiler_machinery, cpu, typed_passes
from numba.core.environment import lookup_environment

from coopsim.compiled.toolchain import resolution
from coopsim.compiled.toolchain.numba_range import supported_numba
from coopsim.compiled.toolchain.scope import ThreadScope

KIND = "coopsim-ir"          # the cache's name for a lazy library's bitcode
_ENV_PREFIX = "_ZN08NumbaEnv"  # numba's mangled name of a function's environment global
_MAKING_LAZY = ThreadScope()   # active while a lazy library's executable is made on this thread


def is_lazy(library) -> bool:
    """Whether `library` is a kernel's lazy code library.

    Args:
        library: a numba code library (`codegen.CodeLibrary`).

    Returns:
        bool: True when `KernelCompiler` made it lazy (or it was loaded lazy from the cache).
    """
    return getattr(library, "_coopsim_lazy", False)


def links_lazy(library) -> bool:
    """Whether `library` links a lazy library, directly or through the libraries it links.

    Args:
        library: a numba code library (`codegen.CodeLibrary`).

    Returns:
        bool: True when a lazy library is among those it links, at any depth.
    """
    seen, todo = set(), list(getattr(library, "_linking_libraries", ()))
    while todo:
        linked = todo.pop()
        if is_lazy(linked):
            return True
        if id(linked) not in seen:
            seen.add(id(linked))
            todo.extend(getattr(linked, "_linking_libraries", ()))
    return False


@compiler_machinery.register_pass(mutates_CFG=False, analysis_only=True)
class LazyLibrary(compiler_machinery.LoweringPass):
    """Pass creating the function's code library before lowering, marked lazy.

    A library handed in by the caller of the pipeline is left as it is.
    """

    _name = "coopsim_lazy_library"

    def __init__(self):
        compiler_machinery.LoweringPass.__init__(self)

    def run_pass(self, state):
        """Create the lazy code library of the function being compiled, unless it has one already.

        Args:
            state: numba's compiler state; state.library is set when None.

        Returns:
            bool: False (the pass changes no IR).
        """
        if state.library is None:
            state.library = state.targetctx.codegen().create_library(state.func_id.func_qualname)
            state.library.enable_object_caching()
            state.library._coopsim_lazy = True
        return False


class KernelCompiler(resolution.CoopsimCompile, compiler.CompilerBase):
    """numba's nopython pipeline, with the code library made lazy (`LazyLibrary`) before lowering.

    A coopsim compile (`resolution.CoopsimCompile`).
    """

    def define_pipelines(self):
        """numba's nopython pipeline with `LazyLibrary` added after type annotation.

        Returns:
            list: the one finalized pass manager.
        """
        pm = compiler.DefaultPassBuilder.define_nopython_pipeline(self.state)
        pm.add_pass_after(LazyLibrary, typed_passes.AnnotateTypes)
        pm.finalize()
        return [pm]


def _module_for_linking(self):
    """A lazy library's module with its callees' linked in, definitions `linkonce_odr` (numba's
    `_get_module_for_linking`, without finalizing)."""
    if self._shared_module is None:
        module = self._final_module.clone()
        seen = set()
        for library in self._linking_libraries:
            if library not in seen:
                seen.add(library)
                module.link_in(library._get_module_for_linking(), preserve=True)
        for fn in module.functions:
            if not fn.is_declaration and fn.linkage == ll.Linkage.external:
                fn.linkage = "linkonce_odr"
        self._shared_module = module
    return self._shared_module


def _unserialize_lazy(codegen_, name, data):
    """A lazy library from its cached bitcode (`serialize_using_object_code`, below)."""
    library = codegen_.create_library(name)
    library._final_module = library._shared_module = ll.parse_bitcode(data)
    library._coopsim_lazy = True
    return library


def _set_environments(library) -> None:
    """Point every function environment global in a finalized library at its environment object (the
    kernels' included: their own libraries never reach the execution engine), those the execution
    engine holds. numba does the same when it loads a library from its cache."""
    engine = library.codegen._engine
    for gv in library._final_module.global_variables:
        if gv.name.startswith(_ENV_PREFIX) and not gv.is_declaration:
            env = lookup_environment(gv.name)
            if env is not None and engine.get_global_value_address(gv.name):
                library.codegen.set_env(gv.name, env)


def install() -> bool:
    """Wrap numba's methods (module docstring); idempotent.

    Returns:
        bool: True if installed (now or before); False, nothing installed, on a numba outside
        `numba_range.NUMBA_RANGE` or without the wrapped methods.
    """
    if not supported_numba():
        return False
    lib, ctx, result = codegen.CPUCodeLibrary, cpu.CPUContext, compiler.CompileResult
    needed = [(codegen.CodeLibrary, "_ensure_finalized"), (lib, "_get_module_for_linking"),
              (lib, "serialize_using_object_code"), (lib, "_unserialize"), (ctx, "get_executable"),
              (codegen.JITCPUCodegen, "set_env"), (result, "_rebuild")]
    if not all(hasattr(owner, name) for owner, name in needed):
        return False
    if getattr(ctx.get_executable, "_coopsim", False):
        return True
    ensure_finalized, module_for_linking = codegen.CodeLibrary._ensure_finalized, lib._get_module_for_linking
    serialize, unserialize = lib.serialize_using_object_code, lib._unserialize.__func__
    get_executable, set_env = ctx.get_executable, codegen.JITCPUCodegen.set_env
    rebuild = result._rebuild.__func__

    def _ensure_finalized(self):
        if not is_lazy(self):
            ensure_finalized(self)

    def _get_module_for_linking(self):
        return _module_for_linking(self) if is_lazy(self) else module_for_linking(self)

    def serialize_using_object_code(self):
        if is_lazy(self):
            return (self.name, KIND, _module_for_linking(self).as_bitcode())
        return serialize(self)

    def _unserialize(cls, codegen_, state):
        name, kind, data = state
        if kind == KIND:
            return _unserialize_lazy(codegen_, name, data)
        return unserialize(cls, codegen_, state)

    def _get_executable(self, library, fndesc, env):
        if is_lazy(library):
            with _MAKING_LAZY():
                return get_executable(self, library, fndesc, env)   # a null function pointer
        cfunc = get_executable(self, library, fndesc, env)
        if links_lazy(library):
            _set_environments(library)
        return cfunc

    def _rebuild(cls, target_context, libdata, *rest):
        if isinstance(libdata, tuple) and len(libdata) == 3 and libdata[1] == KIND:
            with _MAKING_LAZY():
                return rebuild(cls, target_context, libdata, *rest)
        return rebuild(cls, target_context, libdata, *rest)

    def _set_env(self, env_name, env):    # numba writes through a null address for a missing name
        if not _MAKING_LAZY.active or self._engine.get_global_value_address(env_name):
            set_env(self, env_name, env)

    _get_executable._coopsim = True
    codegen.CodeLibrary._ensure_finalized = _ensure_finalized
    lib._get_module_for_linking = _get_module_for_linking
    lib.serialize_using_object_code = serialize_using_object_code
    lib._unserialize = classmethod(_unserialize)
    ctx.get_executable = _get_executable
    result._rebuild = classmethod(_rebuild)
    codegen.JITCPUCodegen.set_env = _set_env
    return True
