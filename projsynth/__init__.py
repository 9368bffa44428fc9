"""projsynth: reproducible projector-camera pairs with exact ground-truth flow.

Convention (everywhere in this package): images are ``H x W x 3`` uint8 RGB, origin top-left,
``x`` right, ``y`` down, pixel centres at integer coordinates. Flow is forward,
projected -> captured, on the projected grid: ``flow[y, x] = (u, v)`` means projected pixel
``(x, y)`` is seen at camera pixel ``(x + u, y + v)``.
"""

__version__ = "0.2.0"

FORMAT_VERSION = 2  # 2: Fletcher-32 on every fixed-size dataset, CRC-32 of the variable-length ones
READABLE_FORMATS = (1, 2)  # what the readers accept (docs/format.md)


class ProjsynthError(Exception):
    """The one error the library raises for bad input; ``cli`` prints it as one line, exit 2."""
