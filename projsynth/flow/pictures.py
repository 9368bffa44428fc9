"""Flow pictures people can read: the colour wheel with its legend and magnitude scale, and labels.

``flow_to_color`` (flowio) saturates at one magnitude; a picture is only comparable with another
drawn at the same one. :func:`flow_picture` draws the flow over a legend strip naming that magnitude
(fixed with ``max_flow``, else the picture's own largest valid one) beside the wheel itself.

Convention: flow projected -> captured, ``(H, W, 2)`` in pixels; pictures uint8 RGB ``H x W x 3``.
"""

from __future__ import annotations

import cv2
import numpy as np

from ..errors import ProjsynthError
from .formats import _as_flow, _as_valid

FONT = cv2.FONT_HERSHEY_SIMPLEX


def font_scale(width: int) -> float:
    """A text scale readable on a picture ``width`` px wide: about 16-20 px high on 512 px."""
    return float(np.clip(width / 700, 0.55, 1.6))


def put_label(image: np.ndarray, text: str, origin: tuple[int, int], scale: float) -> None:
    """Write ``text`` in black on ``image`` (a light strip) in place at ``origin`` (baseline left)."""
    cv2.putText(image, text, origin, FONT, scale, (0, 0, 0), max(1, round(scale * 2)), cv2.LINE_AA)


def text_height(scale: float) -> int:
    """Height in px of a capital letter at ``scale``."""
    return cv2.getTextSize("M", FONT, scale, max(1, round(scale * 2)))[0][1]


def scale_of(flow: np.ndarray, valid: np.ndarray | None, max_flow: float | None) -> float:
    """The magnitude of full saturation: ``max_flow``, else the largest finite valid magnitude (1 if 0)."""
    if max_flow is not None:
        if not (np.isfinite(max_flow) and max_flow > 0):
            raise ProjsynthError(f"--max-flow: must be a positive number of pixels, got {max_flow}")
        return float(max_flow)
    ok = np.isfinite(flow).all(axis=-1) if valid is None else np.isfinite(flow).all(axis=-1) & valid
    f = flow.astype(np.float64)  # as flow_to_color: its largest pixel must not land beyond the scale
    mag = np.hypot(f[..., 0], f[..., 1])[ok]
    return float(mag.max()) if mag.size and mag.max() > 0 else 1.0


def wheel(diameter: int, max_flow: float) -> np.ndarray:
    """The colour wheel as a disk: the colour of a flow pointing from the centre to each pixel, full
    saturation on the rim (``max_flow``); grey outside the disk."""
    r = (diameter - 1) / 2
    ys, xs = np.mgrid[0:diameter, 0:diameter].astype(np.float32)
    flow = np.stack([(xs - r) / r, (ys - r) / r], axis=-1) * max_flow
    inside = np.hypot(xs - r, ys - r) <= r
    disk = flow_to_color(flow, inside, max_flow)
    disk[~inside] = 235
    return disk


def fit(text: str, width: int, scale: float) -> float:
    """``scale``, shrunk so that ``text`` fits in ``width`` px."""
    tw = cv2.getTextSize(text, FONT, scale, max(1, round(scale * 2)))[0][0]
    return scale if tw <= width else max(0.3, scale * width / tw)


def legend(width: int, max_flow: float | None, note: str, scale: float | None = None) -> np.ndarray:
    """A strip ``width`` px wide: the wheel, the magnitude scale (rightward flow from 0, white, to
    ``max_flow``, full colour) labelled at both ends, and ``note`` (where the scale comes from) below;
    ``max_flow`` None: a scale that differs per picture (the right end then names none).

    ``scale``: the text scale (default :func:`font_scale` of ``width``)."""
    scale = font_scale(width) if scale is None else scale
    th = text_height(scale)
    bar_h = max(6, th)
    height = bar_h + 2 * (th + 8) + 10
    strip = np.full((height, width, 3), 235, np.uint8)
    d = height - 8
    m = 1.0 if max_flow is None else max_flow
    if width >= 2 * d:
        strip[4 : 4 + d, 4 : 4 + d] = wheel(d, m)
    else:
        d = -8
    x0, x1 = d + 16, width - 6
    if x1 - x0 < 24:
        return strip
    ramp = np.zeros((1, x1 - x0, 2), np.float32)
    ramp[0, :, 0] = np.linspace(0, m, x1 - x0)
    strip[4 : 4 + bar_h, x0:x1] = flow_to_color(ramp, max_magnitude=m)
    y = 4 + bar_h + th + 6
    put_label(strip, "0 px", (x0, y), fit("0 px", x1 - x0, scale))
    if max_flow is not None:
        right = f"{max_flow:.3g} px"
        s = fit(right, (x1 - x0) // 2, scale)
        tw = cv2.getTextSize(right, FONT, s, max(1, round(s * 2)))[0][0]
        put_label(strip, right, (x1 - tw, y), s)
    put_label(strip, note, (x0, y + th + 8), fit(note, x1 - x0, scale))
    return strip


def flow_picture(flow: np.ndarray, valid: np.ndarray | None = None, max_flow: float | None = None) -> np.ndarray:
    """The flow's colour picture (``flow_to_color``, invalid black) above its legend strip.

    Args:
        flow: ``(H, W, 2)`` float flow in px.
        valid: optional bool ``(H, W)``.
        max_flow: magnitude of full saturation in px; None: the picture's largest valid magnitude.

    Returns:
        uint8 RGB ``(H + L, W, 3)``: rows ``0..H-1`` are ``flow_to_color(flow, valid, scale)``.
    """
    m = scale_of(flow, valid, max_flow)
    color = flow_to_color(flow, valid, m)
    note = "full colour: --max-flow" if max_flow is not None else "full colour: this picture's largest"
    return np.vstack([color, legend(color.shape[1], m, note)])


# Baker et al. wheel, red -> yellow -> green -> cyan -> blue -> magenta -> red:
# (hues, start colour, channel that ramps, +1 ramps up from 0 / -1 ramps down from 255)
_WHEEL_SEGMENTS = (
    (15, (255, 0, 0), 1, 1),
    (6, (255, 255, 0), 0, -1),
    (4, (0, 255, 0), 2, 1),
    (11, (0, 255, 255), 1, -1),
    (13, (0, 0, 255), 0, 1),
    (6, (255, 0, 255), 2, -1),
)


def _make_wheel() -> np.ndarray:
    rows = []
    for n, start, ch, sign in _WHEEL_SEGMENTS:
        seg = np.tile(np.array(start, np.float64), (n, 1))
        seg[:, ch] += sign * np.floor(255 * np.arange(n) / n)
        rows.append(seg)
    return np.concatenate(rows)  # [55, 3] RGB in 0..255


COLOR_WHEEL = _make_wheel()


def flow_to_color(flow: np.ndarray, valid: np.ndarray | None = None, max_magnitude: float | None = None) -> np.ndarray:
    """Colour-code flow with the Baker et al. (Middlebury) 55-hue wheel.

    Hue is the direction (rightward flow is red, leftward cyan-blue), saturation is
    ``|flow| / max_magnitude`` (zero flow is white). Pixels beyond ``max_magnitude`` are drawn at full
    saturation and darkened to 75 %. Invalid and non-finite pixels are black.

    Args:
        flow: ``(H, W, 2)`` floating array.
        valid: optional bool ``(H, W)``; default all pixels.
        max_magnitude: magnitude of full saturation; default the largest valid magnitude (1 if zero).

    Returns:
        uint8 ``(H, W, 3)`` RGB image.

    Convention: flow projected -> captured, in px, ``flow[y, x] = (u, v)``, ``y`` down.

    Example:
        >>> flow_to_color(np.array([[[1.0, 0.0], [0.0, 0.0]]])).tolist()
        [[[255, 0, 0], [255, 255, 255]]]
    """
    flow = _as_flow(flow, "flow_to_color")
    ok = np.isfinite(flow).all(axis=-1)
    if valid is not None:
        ok &= _as_valid(valid, flow.shape, "flow_to_color")
    f = np.where(ok[..., None], flow, 0.0).astype(np.float64)
    rad = np.hypot(f[..., 0], f[..., 1])
    if max_magnitude is None:
        max_magnitude = float(rad.max()) or 1.0
    elif not (np.isfinite(max_magnitude) and max_magnitude > 0):
        raise ProjsynthError(f"flow_to_color: max_magnitude must be positive and finite, got {max_magnitude}")
    rad = rad[..., None] / max_magnitude
    n = len(COLOR_WHEEL)
    # "+ 0.0" turns -0.0 into +0.0, so that v = +-0 land on the same side of the wheel's seam
    a = np.arctan2(-(f[..., 1] + 0.0), -f[..., 0]) / np.pi  # [-1, 1]; -1 (and 1) is rightward
    fk = (a + 1) / 2 * (n - 1)
    k0 = np.floor(fk).astype(np.int64)
    t = (fk - k0)[..., None]
    col = (1 - t) * COLOR_WHEEL[k0] + t * COLOR_WHEEL[(k0 + 1) % n]  # [H, W, 3] in 0..255
    col = np.where(rad <= 1, 255 - rad * (255 - col), 0.75 * col)
    rgb = np.floor(col).astype(np.uint8)
    rgb[~ok] = 0
    return rgb
