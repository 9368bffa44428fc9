"""projreg: the SSJM registration network: train, benchmark and apply it to projector-camera pairs.

The in-memory API (:mod:`projreg.api`, docs/api.md) is exported here: ``Registrar``, ``Registration``,
``compensate``, ``warp_map``, ``export_warp``, ``end_point_error``; it is imported on first use (it loads
torch).
"""

from .errors import ProjregError
from .versions import __version__

_API = ("Registrar", "Registration", "compensate", "warp_map", "export_warp", "end_point_error")
__all__ = ["ProjregError", "__version__", *_API]


def __getattr__(name: str):  # noqa: ANN202 - the API's names, loaded on first use
    if name in _API:
        from . import api

        return getattr(api, name)
    raise AttributeError(f"module 'projreg' has no attribute {name!r}")
