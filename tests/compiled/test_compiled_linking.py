"""Lazy kernels (coopsim.compiled.toolchain.linking): a kernel is compiled to LLVM IR only, cached as IR, and
becomes machine code inside the entries that call it; remembered call-type resolution
(coopsim.compiled.toolchain.resolution) gives numba's own answers; code loads from the cache without numba's
compiler registries (coopsim.compiled.toolchain.loading), and a later compile still has them. Each case runs
in fresh processes over a kernel and two entries written to a temporary folder, with numba's cache
there; results exact (the arithmetic is exact in binary floating point)."""

import json
import operator
import os
import re
import subprocess
import sys
import textwrap

import numba
import pytest
from helpers import LINKING_MODULE as MODULE
from helpers import ROOT
from numba import types
from numba.core import errors
from numba.core.registry import cpu_target
from numba.core.types import functions

from coopsim.compiled.toolchain import linking, numba_range, resolution

PROBE = textwrap.dedent('''
    import json, sys
    import numpy as np
    import lazymod
    from coopsim.compiled.toolchain import linking

    out = {}
    numba_np = lambda: sorted(m for m in ("numba.np.arraymath", "numba.np.linalg", "numba.np.npdatetime",
                                          "numba.typed.typeddict", "scipy.linalg") if m in sys.modules)
    for name in sys.argv[1:]:
        fn = getattr(lazymod, name)
        out[name] = fn(0.5, np.array([1.0, 2.0, 4.0]), np.array([1.0, 1.0, 1.0]))
        out[name + "_hits"] = sum(fn.stats.cache_hits.values())
        (cres,) = fn.overloads.values()
        out[name + "_finalized"] = cres.library._finalized
    kernel = lazymod.axpy
    out["kernel_hits"] = sum(kernel.stats.cache_hits.values())
    out["kernel_compiled"] = len(kernel.overloads)
    if kernel.overloads:
        (cres,) = kernel.overloads.values()
        out["kernel_lazy"] = linking.is_lazy(cres.library)
        out["kernel_finalized"] = cres.library._finalized
    out["registries_before_compile"] = numba_np()
    from numba import njit
    out["fresh_compile"] = njit(lambda n: np.arange(n * 1.0).sum())(4)
    out["registries_after_compile"] = len(numba_np()) > 0
    print(json.dumps(out))
''')


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """Three fresh processes in turn over one cache: `first`; then `second`; then both."""
    folder = tmp_path_factory.mktemp("lazy")
    (folder / "lazymod.py").write_text(MODULE)
    (folder / "probe.py").write_text(PROBE)
    env = dict(os.environ, NUMBA_CACHE_DIR=str(folder / "cache"),
               PYTHONPATH=os.pathsep.join([str(folder), os.environ.get("PYTHONPATH", "")]))

    def run(*entries):
        done = subprocess.run([sys.executable, str(folder / "probe.py"), *entries], env=env,
                              capture_output=True, text=True, timeout=300)
        assert done.returncode == 0, done.stderr[-2000:]
        return json.loads(done.stdout.splitlines()[-1])

    return run("first"), run("second"), run("first", "second")


def test_a_kernel_stays_ir_and_its_entries_run_it(runs):
    """First process: the entry compiles the kernel, which is lazy and never finalized; the entry is
    machine code and gives 0.5·(1, 2, 4) + 1 summed = 6.5."""
    out = runs[0]
    assert out["first"] == 6.5
    assert out["first_finalized"] and out["first_hits"] == 0
    assert out["kernel_compiled"] == 1 and out["kernel_lazy"] and not out["kernel_finalized"]


def test_another_process_links_the_cached_kernel(runs):
    """Second process: a new entry loads the kernel from the cache (as IR, still lazy) and links it:
    2 × 6.5 = 13."""
    out = runs[1]
    assert out["second"] == 13.0 and out["second_hits"] == 0
    assert out["kernel_hits"] == 1 and out["kernel_lazy"] and not out["kernel_finalized"]


def test_cached_entries_load_without_the_kernel(runs):
    """Third process: both entries come from the cache whole; the kernel is not even loaded."""
    out = runs[2]
    assert (out["first"], out["second"]) == (6.5, 13.0)
    assert out["first_hits"] == out["second_hits"] == 1 and out["kernel_compiled"] == 0


def test_cached_code_loads_without_numbas_registries_and_a_compile_still_has_them(runs):
    """Third process: loading both entries imported none of the registries numba's refresh imports
    (its NumPy math, linear algebra and datetime lowering, typed dict, SciPy's linear algebra); a
    function compiled afterwards in the same process (np.arange(4.0).sum() = 6) gets them."""
    out = runs[2]
    assert out["registries_before_compile"] == []
    assert out["fresh_compile"] == 6.0 and out["registries_after_compile"]


def test_install_is_idempotent():
    assert linking.install() and linking.install()
    assert resolution.install() and resolution.install()


@pytest.mark.parametrize("op, args", [
    (operator.mul, (types.float64, types.float64)),
    (operator.add, (types.int64, types.float64)),
    (operator.getitem, (types.Array(types.float64, 2, "C"), types.UniTuple(types.int64, 2))),
    (operator.setitem, (types.Array(types.float64, 1, "C"), types.int64, types.float64)),
])
def test_remembered_resolution_is_numbas(op, args):
    """The remembered signature, asked twice, is the one numba's own resolution gives."""
    context = cpu_target.typing_context
    context.refresh()
    fnty = context.resolve_value_type(op)
    numba_own = functions.BaseFunction.get_call_type.__wrapped__
    with resolution.coopsim_compile():           # the memo is read and filled only inside one
        first, again = fnty.get_call_type(context, args, {}), fnty.get_call_type(context, args, {})
    assert first == again == numba_own(fnty, context, args, {})


def test_a_failed_resolution_is_not_remembered():
    """No signature for float64 × unicode: numba reports it each time it is asked."""
    context = cpu_target.typing_context
    fnty = context.resolve_value_type(operator.mul)
    for _ in range(2):
        with pytest.raises(errors.TypingError):
            fnty.get_call_type(context, (types.float64, types.unicode_type), {})


@pytest.mark.parametrize("version, ok", [("0.68.1", True), ("0.68.0", True), ("0.69.0rc1", False),
                                         ("0.67.0", False), ("0.60.0", False), ("1.0.0", False)])
def test_the_wrappers_install_only_on_the_numba_versions_they_follow(version, ok):
    assert numba_range.supported_numba(version) is ok


def test_the_declared_numba_range_is_the_gate_and_the_one_running():
    """pyproject's `numba>=A,<B` is the wrappers' gate [A, B), and the suite runs on a numba inside it
    (so the wrappers are what it exercises)."""
    text = (ROOT / "pyproject.toml").read_text()
    declared = re.search(r'"numba>=(\d+)\.(\d+),<(\d+)\.(\d+)"', text)
    assert declared, "pyproject.toml: numba's requirement is not of the form numba>=A.B,<C.D"
    a, b, c, d = map(int, declared.groups())
    assert numba_range.NUMBA_RANGE == ((a, b), (c, d))
    assert numba_range.supported_numba(), f"numba {numba.__version__} outside {numba_range.NUMBA_RANGE}"
