"""The numba versions whose internals the compile-time wrappers (`linking`, `resolution`, `loading`)
follow, and the test of the running numba against them.

The range is the one the suite exercises and `pyproject.toml` declares (`numba>=0.68,<0.69`):
`tests/compiled/test_compiled_linking.py` checks the three agree. On any other numba the wrappers install
nothing and numba compiles coopsim as it does by default (a slower first compile, the same code).
"""

from __future__ import annotations

import numba

NUMBA_RANGE = ((0, 68), (0, 69))   # [low, high) as (major, minor)


def supported_numba(version: str | None = None) -> bool:
    """Whether a numba version is in NUMBA_RANGE.

    Args:
        version: a version string such as "0.68.1"; None for the running numba's.

    Returns:
        True if its (major, minor) lies in [NUMBA_RANGE[0], NUMBA_RANGE[1]).
    """
    parts = tuple(int(p) for p in (version or numba.__version__).split(".")[:2] if p.isdigit())
    return NUMBA_RANGE[0] <= parts < NUMBA_RANGE[1]
