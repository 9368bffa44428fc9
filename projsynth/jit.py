"""numba's ``njit`` with the project's options, for the per-pixel geometry and sampling kernels.

* ``cache=True``: compiled once per machine and kept beside the module (or in numba's user cache when
  the package directory is read-only), so worker processes load the machine code instead of compiling.
  numba keys that cache on the kernel's own source file only: after editing a helper that another
  module's kernels inline (``surface.py``, ``lens.py``), ``make clean-kernels`` drops the stale code.
  (Installing another version writes every file anew, so their stamps change.)
* No ``fastmath``: IEEE semantics, so a sample's bytes do not depend on how the compiler reorders sums.
* ``error_model="numpy"``: ``x / 0.0`` gives ``inf`` or ``nan`` as in numpy instead of raising.
"""

from collections.abc import Callable

import numba


def jit(fn: Callable | None = None, *, inline: bool = False) -> Callable:
    """Compile ``fn`` with numba in nopython mode (see the module docstring for the options).

    ``@jit(inline=True)`` inlines a small per-pixel helper into its callers at numba's level: an
    ordinary call passes the packed lens or surface on the stack and reference-counts its arrays,
    which cost more than a plane's whole ray cast.
    """
    options = {"cache": True, "error_model": "numpy", "nogil": True, "inline": "always" if inline else "never"}
    return numba.njit(**options) if fn is None else numba.njit(**options)(fn)
