"""projsynth: reproducible projector-camera pairs with exact ground-truth flow.

Convention (everywhere in this package): images are ``H x W x 3`` uint8 RGB, origin top-left,
``x`` right, ``y`` down, pixel centres at integer coordinates. Flow is forward,
projected -> captured, on the projected grid: ``flow[y, x] = (u, v)`` means projected pixel
``(x, y)`` is seen at camera pixel ``(x + u, y + v)``.

The in-memory API (:mod:`projsynth.api`, docs/api.md) is exported here: ``open_dataset``,
``render_pair``, ``make_patterns``, ``decode_photos``, ``fit_device_response``; it is imported on first use.
"""

from .errors import ProjsynthError
from .versions import FORMAT_VERSION, READABLE_FORMATS, __version__

_API = ("Dataset", "open_dataset", "render_pair", "make_patterns", "decode_photos", "fit_device_response")
__all__ = ["FORMAT_VERSION", "READABLE_FORMATS", "ProjsynthError", "__version__", *_API]


def __getattr__(name: str):  # noqa: ANN202 - the API's names, loaded on first use
    if name in _API:
        from . import api

        return getattr(api, name)
    raise AttributeError(f"module 'projsynth' has no attribute {name!r}")
