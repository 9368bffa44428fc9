"""numba's ``njit`` with the project's options, for the per-pixel geometry and sampling kernels.

* ``cache=True``: compiled once per machine and kept beside the module (or in numba's user cache when
  the package directory is read-only), so worker processes load the machine code instead of compiling.
  numba keys that cache on the kernel's own source file only: after editing a helper that another
  module's kernels inline (``surface.py``, ``lens.py``), ``make clean-kernels`` drops the stale code.
  (Installing another version writes every file anew, so their stamps change.)
* No ``fastmath``: IEEE semantics, so a sample's bytes do not depend on how the compiler reorders sums.
* ``error_model="numpy"``: ``x / 0.0`` gives ``inf`` or ``nan`` as in numpy instead of raising.
"""

import os
from collections.abc import Callable

import numba

KERNELS: list = []  # every compiled (not inlined) kernel, for :func:`uncompiled_kernels`


def jit(fn: Callable | None = None, *, inline: bool = False) -> Callable:
    """Compile ``fn`` with numba in nopython mode (see the module docstring for the options).

    ``@jit(inline=True)`` inlines a small per-pixel helper into its callers at numba's level: an
    ordinary call passes the packed lens or surface on the stack and reference-counts its arrays,
    which cost more than a plane's whole ray cast.
    """
    options = {"cache": True, "error_model": "numpy", "nogil": True, "inline": "always" if inline else "never"}
    if fn is None:
        return lambda f: jit(f, inline=inline)
    kernel = numba.njit(**options)(fn)
    if not inline:
        KERNELS.append(kernel)
    return kernel


def uncompiled_kernels() -> list[str]:
    """Names of the kernels that numba's on-disk cache does not hold yet (all of them on a first run).

    Only whether an index file exists is checked: a stale entry (an edited kernel) still counts as
    compiled here, and numba recompiles it on first call as usual.
    """
    missing = []
    for kernel in KERNELS:
        cache = getattr(kernel, "_cache", None)
        index = getattr(getattr(cache, "_cache_file", None), "_index_path", None)
        if index is None or not os.path.exists(index):
            missing.append(kernel.py_func.__qualname__)
    return missing
