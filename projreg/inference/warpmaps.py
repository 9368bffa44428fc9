"""Warp maps: the pre-warp of ``projreg compensate`` as a map that show software applies to every frame.

``compensate`` pre-warps one picture; a media server plays video, so it needs the warp itself: for
every projector pixel, the content point it shows and whether it shows content at all.
:func:`warp_map` gives both for a registration's flow under compensate's coverage policy
(:mod:`projreg.inference.compensate`): the same pixels show content, and a pair not registered is
projected as it is (the identity map: the content resized to the projector's frame).

Convention (an STMap's, as Nuke and TouchDesigner read it): the content point in normalised UV,
``u = (x + 0.5) / W`` to the right and ``v = 1 - (y + 0.5) / H`` up, with ``(x, y)`` in content
pixels (pixel centres at integers, ``y`` down) and ``W x H`` the content's size; ``(0, 0)`` is the
content's bottom-left corner, ``(1, 1)`` its top-right one. The content spans the camera frame, so
``(u, v)`` is the camera-frame position compensate samples, normalised: one map serves content of
any resolution. A projector pixel that shows no content has ``u = v = OUTSIDE``, off the content.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..checks import is_int
from ..errors import ProjregError
from ..geometry.warp import pixel_maps
from .compensate import as_it_is, content_mask, shown_pixels

MAX_CONTENT_SIDE = 16384  # cv2.remap's fixed-point positions hold +-32767 px; larger content is not a frame
OUTSIDE = -1.0  # UV of the projector pixels that show no content: a whole frame off it, for tools that ignore alpha


@dataclass(frozen=True)
class WarpMap:
    """Where each projector pixel takes its content (module convention).

    ``uv``: float32 ``(H, W, 2)`` on the projector grid, ``(u, v)`` of the content point, ``OUTSIDE``
    where ``shown`` is False; ``shown``: bool ``(H, W)``, the projector pixels that show content
    (:func:`projreg.inference.compensate.content_mask`); ``camera_size``: the camera frame ``(Hc, Wc)``
    the content spans, in whose pixels errors of the map are measured.
    """

    uv: np.ndarray
    shown: np.ndarray
    camera_size: tuple[int, int]

    def stmap(self) -> np.ndarray:
        """The STMap, float32 ``(H, W, 4)``: R = u, G = v, B = 0, A = 1 where content is shown, else 0."""
        h, w = self.shown.shape
        rgba = np.zeros((h, w, 4), np.float32)
        rgba[..., :2] = self.uv
        rgba[..., 3] = self.shown
        return rgba

    def remap_maps(self, content_size: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
        """``cv2.remap``'s ``map_x``, ``map_y`` (float32 ``(H, W)``) in pixels of a content of ``content_size``
        ``(Hc', Wc')``: ``x = u Wc' - 0.5``, ``y = (1 - v) Hc' - 0.5``.

        On shown pixels the positions are clamped to the content's outer pixel centres, which for
        bilinear sampling is exactly compensate's replicated border: ``cv2.remap(content, map_x, map_y,
        cv2.INTER_LINEAR)`` with its default constant border gives compensate's image there, and black
        (the border value) on the other pixels, whose positions lie a frame off the content.

        Raises:
            ProjregError: ``content_size`` is not two integers in 1..``MAX_CONTENT_SIDE``.
        """
        ch, cw = check_content_size(content_size, "content_size")
        x = self.uv[..., 0].astype(np.float64) * cw - 0.5
        y = (1 - self.uv[..., 1].astype(np.float64)) * ch - 0.5
        x = np.where(self.shown, np.clip(x, 0, cw - 1), x)
        y = np.where(self.shown, np.clip(y, 0, ch - 1), y)
        return x.astype(np.float32), y.astype(np.float32)

    def error(self, other: WarpMap) -> np.ndarray:
        """Distance between this map's content points and ``other``'s, in camera pixels, float64 ``(H, W)``."""
        d = (self.uv.astype(np.float64) - other.uv) * (self.camera_size[1], self.camera_size[0])
        return np.hypot(d[..., 0], d[..., 1])


def check_content_size(content_size: object, name: str) -> tuple[int, int]:
    """``content_size`` as ``(H, W)`` if it is two integers (numpy's included) in 1..``MAX_CONTENT_SIDE``,
    else one line naming ``name``."""
    if (
        not isinstance(content_size, tuple | list | np.ndarray)
        or len(content_size) != 2
        or not all(is_int(v) and 1 <= v <= MAX_CONTENT_SIDE for v in content_size)
    ):
        raise ProjregError(f"{name}: expected two integers in 1..{MAX_CONTENT_SIDE}, got {content_size!r}")
    return int(content_size[0]), int(content_size[1])


def warp_map(
    flow: np.ndarray,
    *,
    claimed: np.ndarray | None = None,
    confidence: np.ndarray | None = None,
    registered: bool = True,
    coverage: str = "complete",
    min_confidence: float = 0.0,
    camera_size: tuple[int, int] | None = None,
) -> WarpMap:
    """The warp map of a registration's flow: what :func:`projreg.inference.compensate.prewarp` does with
    the same arguments, as a map (module docstring).

    Args:
        flow: ``(H, W, 2)`` forward flow projected -> captured, in pixels of the camera frame.
        claimed, confidence, registered, coverage, min_confidence: the registration's claim (bool
            ``(H, W)``), confidence (float ``(H, W)``) and verdict, and the coverage asked, as ``prewarp``.
        camera_size: the camera frame ``(Hc, Wc)`` the flow's positions are in; None: ``(H, W)``.

    Returns:
        The :class:`WarpMap`: projector pixel ``p`` shows the content at camera position ``p + F(p)``,
        ``u = (x + u_F + 0.5) / Wc``, ``v = 1 - (y + v_F + 0.5) / Hc``; a pair projected as it is,
        ``u = (x + 0.5) / W``, ``v = 1 - (y + 0.5) / H``.

    Raises:
        ProjregError: a flow that is not ``(H, W, 2)``, a bad coverage option (as ``prewarp``), or no
            projector pixel left to show content.

    Example:
        >>> m = warp_map(np.full((2, 4, 2), 1.0, np.float32), camera_size=(4, 8))
        >>> m.uv[0, 0].tolist(), bool(m.shown.all())
        ([0.1875, 0.625], True)
    """
    flow = np.asarray(flow)
    if flow.ndim != 3 or flow.shape[2] != 2:
        raise ProjregError(f"flow has shape {flow.shape}, expected (H, W, 2)")
    h, w = flow.shape[:2]
    cam_h, cam_w = camera_size or (h, w)
    shown = content_mask(
        flow, shown_pixels(claimed, confidence, coverage, min_confidence), registered, coverage, (cam_h, cam_w)
    )
    if not shown.any():
        raise ProjregError("flow has no finite valid vector inside the camera frame: no projector pixel shows content")
    xs, ys = pixel_maps(h, w)
    if as_it_is(registered, coverage):  # the content resized to the projector's frame
        x, y, size = xs.astype(np.float64), ys.astype(np.float64), (h, w)
    else:  # the camera position p + F(p) (not finite only where nothing is shown)
        x, y, size = xs + flow[..., 0].astype(np.float64), ys + flow[..., 1].astype(np.float64), (cam_h, cam_w)
    uv = np.stack([(x + 0.5) / size[1], 1 - (y + 0.5) / size[0]], axis=-1)  # [H, W, 2]
    uv = np.where(shown[..., None], uv, OUTSIDE).astype(np.float32)
    return WarpMap(uv, shown, (cam_h, cam_w))
