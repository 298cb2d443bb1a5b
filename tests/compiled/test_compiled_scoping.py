"""coopsim's changes to numba (coopsim.compiled.toolchain.linking, resolution, loading) apply to coopsim's
functions only: a user's own `@njit(cache=True)` function compiled, cached and loaded in a process
that imported coopsim.compiled is handled as stock numba handles it. With COOPSIM_STOCK_NUMBA=1 none
of the changes is installed and coopsim's compiled code gives the same numbers, to the last bit.

The end-to-end cases run in fresh processes: a module of coopsim functions (a kernel and an entry,
compiled with coopsim's decorators) and a module of a user's function are written to a temporary
folder, and numba's cache folder is set to another one once coopsim's own functions are decorated
(they load from the cache the session's warm-up filled)."""

import json
import os
import subprocess
import sys
import textwrap

import numpy as np
from helpers import LINKING_MODULE as MODULE
from helpers import SCENARIOS

from coopsim.compiled import api
from coopsim.compiled.toolchain import resolution

PAPER = str(SCENARIOS / "paper_planar_2x3.yaml")

COOPMOD = MODULE   # a kernel (axpy) and two entries calling it, compiled with coopsim's decorators


USERMOD = textwrap.dedent('''
    from numba import njit


    @njit(cache=True)
    def user(x):
        s = 0.0
        for i in range(x.shape[0]):
            s += x[i] * x[i] - 0.5 * x[i]
        return s
''')

# numba's target-context refresh, which precedes every cache load, imports this registry
REGISTRY = "numba.np.linalg"

COMPILE = textwrap.dedent('''
    import json, sys
    import numpy as np
    from numba.core import config
    from coopsim.compiled import api
    from coopsim.compiled.toolchain import linking
    from coopsim.compiled.toolchain import resolution
    from coopsim.io.scenario import load_scenario

    model = load_scenario(sys.argv[2])
    api.forward(model, model.q0, model.qd0, np.zeros(model.n_total))   # coopsim's code, from the cache
    config.CACHE_DIR = sys.argv[1]
    envs = []
    set_environments = linking._set_environments
    linking._set_environments = lambda library: (envs.append(library.name), set_environments(library))[1]
    import coopmod, usermod

    out = {"entry": coopmod.first(0.5, np.array([1.0, 2.0, 4.0]), np.ones(3))}   # compiled: fills the memo
    out["entry_envs"], out["memo_after_entry"] = len(envs), len(resolution._MEMO)
    out["user"] = usermod.user(np.array([1.0, 2.0, 4.0]))
    out["user_envs"], out["memo_after_user"] = len(envs) - out["entry_envs"], len(resolution._MEMO)
    (cres,) = usermod.user.overloads.values()
    out["user_lazy"], out["user_finalized"] = linking.is_lazy(cres.library), cres.library._finalized
    out["user_hits"] = sum(usermod.user.stats.cache_hits.values())
    out["making_lazy"] = linking._MAKING_LAZY.active


    def kinds(fn):
        """The serialization kinds of `fn`'s cached libraries, as numba reads its cache files."""
        cache_file = fn._cache._cache_file
        return [cache_file._load_data(name)[0][1] for name in cache_file._load_index().values()]


    out["user_kinds"], out["kernel_kinds"] = kinds(usermod.user), kinds(coopmod.axpy)
    out["user_cache_path"] = usermod.user._cache.cache_path
    print(json.dumps(out))
''')

LOAD = textwrap.dedent('''
    import json, sys
    import numpy as np
    from numba.core import config

    out = {}
    if sys.argv[2] != "-":
        from coopsim.compiled import api
        from coopsim.io.scenario import load_scenario

        model = load_scenario(sys.argv[2])
        api.forward(model, model.q0, model.qd0, np.zeros(model.n_total))
        config.CACHE_DIR = sys.argv[1]
        import coopmod

        out["entry"] = coopmod.first(0.5, np.array([1.0, 2.0, 4.0]), np.ones(3))
        out["entry_hits"] = sum(coopmod.first.stats.cache_hits.values())
    config.CACHE_DIR = sys.argv[1]
    import usermod

    out["registry_before_user"] = "REGISTRY" in sys.modules
    out["user"] = usermod.user(np.array([1.0, 2.0, 4.0]))
    out["user_hits"] = sum(usermod.user.stats.cache_hits.values())
    out["registry_after_user"] = "REGISTRY" in sys.modules
    print(json.dumps(out))
''').replace("REGISTRY", REGISTRY)


def _run(code, *args, env, cwd):
    done = subprocess.run([sys.executable, "-c", code, *args], env=env, cwd=cwd, capture_output=True,
                          text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-3000:]
    return json.loads(done.stdout.splitlines()[-1])


USER = 1 + 4 + 16 - 0.5 * 7     # usermod.user((1, 2, 4))


def test_a_user_function_compiles_caches_and_loads_as_stock_numba_after_coopsim(tmp_path):
    """Three processes over one fresh cache (one test: the processes take most of its time).
    First, after coopsim's code loaded and a coopsim entry compiled (0.5·(1, 2, 4) + 1 summed = 6.5,
    resolutions remembered, its kernel's environment set), the user's function compiles: a finalized
    library of numba's, no environment set by coopsim, no resolution remembered, cached in the
    folder given, as numba's object code (the kernel as coopsim's IR). Second: coopsim's code loads
    from the cache without numba's target-context refresh (the registry it imports is still absent
    after the coopsim entry loaded), and the user's function loads with it, as in a process that
    never imports coopsim (the third)."""
    (tmp_path / "coopmod.py").write_text(COOPMOD)
    (tmp_path / "usermod.py").write_text(USERMOD)
    cache = str(tmp_path / "cache")
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(tmp_path), os.environ.get("PYTHONPATH", "")]))
    env.pop("COOPSIM_STOCK_NUMBA", None)

    out = _run(COMPILE, cache, PAPER, env=env, cwd=tmp_path)
    assert out["entry"] == 6.5 and out["entry_envs"] == 1 and out["memo_after_entry"] > 0
    assert out["user"] == USER and out["user_hits"] == 0
    assert out["user_finalized"] and not out["user_lazy"]
    assert out["user_envs"] == 0, "coopsim set the environments of the user's library"
    assert out["memo_after_user"] == out["memo_after_entry"], "the user's compile used coopsim's memo"
    assert not out["making_lazy"]
    assert out["user_kinds"] == ["object"] and out["kernel_kinds"] == ["coopsim-ir"]
    assert os.path.commonpath([out["user_cache_path"], cache]) == cache

    coopsim_first = _run(LOAD, cache, PAPER, env=env, cwd=tmp_path)
    stock = _run(LOAD, cache, "-", env=env, cwd=tmp_path)
    assert coopsim_first["entry"] == 6.5 and coopsim_first["entry_hits"] == 1
    assert stock["user_hits"] == coopsim_first["user_hits"] == 1
    assert stock["user"] == coopsim_first["user"] == USER
    assert (stock["registry_before_user"], stock["registry_after_user"]) == (False, True)
    assert (coopsim_first["registry_before_user"], coopsim_first["registry_after_user"]) == (False, True)


def test_remembered_resolution_applies_in_a_coopsim_compile_only():
    """Outside a coopsim compile numba resolves (nothing remembered); inside one the remembered
    signature is numba's own."""
    import operator

    from numba import types
    from numba.core.registry import cpu_target
    from numba.core.types import functions

    context = cpu_target.typing_context
    context.refresh()
    fnty = context.resolve_value_type(operator.truediv)
    args = (types.int32, types.float32)
    numba_own = functions.BaseFunction.get_call_type.__wrapped__(fnty, context, args, {})
    key = (fnty, context, args, (), None)      # the memo's key of this call outside numba's compiler
    assert fnty.get_call_type(context, args, {}) == numba_own and key not in resolution._MEMO
    assert not resolution.in_coopsim_compile()
    with resolution.coopsim_compile():
        assert resolution.in_coopsim_compile()
        first, again = fnty.get_call_type(context, args, {}), fnty.get_call_type(context, args, {})
    assert first == again == numba_own and key in resolution._MEMO
    assert not resolution.in_coopsim_compile()


STOCK = textwrap.dedent('''
    import json, sys
    import numpy as np
    from numba.core import caching, cpu
    from numba.core.types import functions
    from coopsim.compiled import api, ik, kinematics
    from coopsim.compiled.toolchain import jit
    from coopsim.compiled.toolchain import linking
    from coopsim.io.scenario import load_scenario

    out = {"stock": jit.STOCK, "wrapped": [getattr(f, "_coopsim", False) for f in (
        cpu.CPUContext.get_executable, functions.BaseFunction.get_call_type, caching.Cache.load_overload)]}
    model = load_scenario(sys.argv[1])
    m, *arrays = json.loads(sys.argv[2])
    sol = api.solve_arm(model, m, *[np.array(a) for a in arrays], max_iter=20)
    out.update(status=sol.status, q=sol.q.tolist(), qd=sol.qd.tolist(), qdd=sol.qdd.tolist(),
               info=[sol.ratio, sol.det, sol.full_error])
    (cres,) = kinematics.arm_kinematics.overloads.values()
    out["kernel_lazy"], out["kernel_finalized"] = linking.is_lazy(cres.library), cres.library._finalized
    out["cache_path"] = ik.arm_solve._cache.cache_path
    print(json.dumps(out))
''')


def test_stock_numba_gives_the_same_numbers(paper, tmp_path):
    """COOPSIM_STOCK_NUMBA=1, in a fresh process and cache: nothing of coopsim's is installed, a kernel
    is finalized as numba does, coopsim's code is cached in a folder of its own, and arm 0's inverse
    kinematics (a compiled entry and its kernels; compiled stock in a few seconds) gives what this
    process's (coopsim's compile) gives, bit for bit."""
    args = [0, [0.9, 0.4, 0.0], np.eye(3).tolist(), [0.1] * 6, [0.2] * 6, (paper.q0 + 0.1).tolist()]
    env = dict(os.environ, COOPSIM_STOCK_NUMBA="1", NUMBA_CACHE_DIR=str(tmp_path / "cache"))
    out = _run(STOCK, PAPER, json.dumps(args), env=env, cwd=tmp_path)
    assert out["stock"] and out["wrapped"] == [False, False, False]
    assert not out["kernel_lazy"] and out["kernel_finalized"]
    assert "stock-numba" in out["cache_path"].split(os.sep)
    here = api.solve_arm(paper, args[0], *[np.array(a) for a in args[1:]], max_iter=20)
    assert out["status"] == here.status == 0
    for name in ("q", "qd", "qdd"):
        assert np.array_equal(np.array(out[name]), getattr(here, name)), name
    assert out["info"] == [here.ratio, here.det, here.full_error]


def test_setting_an_environment_is_numbas_unless_a_lazy_librarys_executable_is_made():
    """numba's `set_env` looks the global up and writes the environment's address there; coopsim's
    skip of a global the execution engine does not hold applies while a lazy library's executable is
    made only (a stand-in engine: one slot, "present")."""
    import ctypes
    from types import SimpleNamespace

    from numba.core import codegen

    from coopsim.compiled.toolchain import linking

    slot, asked = (ctypes.c_void_p * 1)(), []

    def address(name):
        asked.append(name)
        return ctypes.addressof(slot) if name == "present" else 0

    engine, env = SimpleNamespace(_engine=SimpleNamespace(get_global_value_address=address)), object()
    codegen.JITCPUCodegen.set_env(engine, "present", env)
    assert slot[0] == id(env) and asked == ["present"]          # numba's: one look-up, then the write
    slot[0], asked[:] = None, []
    with linking._MAKING_LAZY():
        codegen.JITCPUCodegen.set_env(engine, "missing", env)    # numba would write through address 0
        codegen.JITCPUCodegen.set_env(engine, "present", env)
    assert slot[0] == id(env) and asked == ["missing", "present", "present"]
    assert not linking._MAKING_LAZY.active
