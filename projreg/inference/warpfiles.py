"""The files of ``projreg warp``: a registration's warp map for show software, in the format its name's
suffix says (docs/show.md), written whole or not at all.

* ``.exr``: the STMap (:meth:`~projreg.inference.warpmaps.WarpMap.stmap`), channels R, G, B, A, 32-bit
  float, ZIP-compressed, one part of scanlines, the projector's size; the header's ``comments`` says
  the convention.
* ``.obj``: the mesh (:mod:`projreg.inference.warpmesh`), a vertex every ``step`` projector pixels.
* ``.npz``: ``map_x``, ``map_y`` (float32, for ``cv2.remap`` in pixels of a content of ``content_size``,
  :meth:`~projreg.inference.warpmaps.WarpMap.remap_maps`), ``shown`` (bool) and ``content_size``
  (int ``[H, W]``), as ``numpy.savez_compressed`` writes them.

Convention: projector pixels, content UV and positions as :mod:`projreg.inference.warpmaps` says.
"""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
import OpenEXR

from projsynth.errors import ProjsynthError
from projsynth.flow.formats import read_flow_file
from projsynth.utils.files import write_atomic

from ..errors import ProjregError
from .compensate import as_it_is, check_aspect, file_coverage, stated_camera_size
from .outputs import guard_outputs
from .warpmaps import WarpMap, check_content_size, warp_map
from .warpmesh import DEFAULT_STEP, grid_mesh, mesh_error, obj_text, used_vertices

FORMATS = {".exr": "STMap", ".obj": "mesh", ".npz": "cv2.remap maps"}  # by the suffix of --out
CONVENTION = (
    "projector pixel (x, y) shows the content point u = (x' + 0.5) / W, v = 1 - (y' + 0.5) / H, where (x', y') "
    "are content pixels (centres at integers, y down) of a W x H content spanning the camera frame"
)


def warp_format(out: Path) -> str:
    """The suffix of ``out`` (lower case) if it names a warp format, else one line naming ``--out``."""
    suffix = Path(out).suffix.lower()
    if suffix not in FORMATS:
        named = ", ".join(f"{s} ({what})" for s, what in FORMATS.items())
        raise ProjregError(f"--out {out}: not a warp format ({suffix or 'no suffix'}); give a name ending in {named}")
    return suffix


def check_options(suffix: str, step: int | None, content_size: tuple[int, int] | None) -> None:
    """Refuse an option the format of ``suffix`` does not use, rather than ignore it, and a content size
    out of bounds."""
    if step is not None and suffix != ".obj":
        raise ProjregError(f"--step sets the grid of a mesh (.obj); a {FORMATS[suffix]} has one value per pixel")
    if content_size is None:
        return
    if suffix != ".npz":
        raise ProjregError(
            f"--content-size is for cv2.remap maps (.npz), in content pixels; a {FORMATS[suffix]} is in normalised "
            "UV, for content of any size"
        )
    check_content_size(content_size, "--content-size")


def encode_stmap(m: WarpMap, comments: str) -> bytes:
    """The STMap of ``m`` as a complete OpenEXR file, in memory (module docstring)."""
    rgba = m.stmap()
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage, "comments": comments}
    channels = {name: np.ascontiguousarray(rgba[..., i]) for i, name in enumerate("RGBA")}  # one copy each
    buf = io.BytesIO()
    OpenEXR.File(header, channels).write(buf)
    return buf.getvalue()


def encode_npz(m: WarpMap, content_size: tuple[int, int]) -> bytes:
    """``m``'s ``cv2.remap`` maps for a content of ``content_size`` ``(H, W)`` as an ``.npz`` file, in memory."""
    map_x, map_y = m.remap_maps(content_size)
    buf = io.BytesIO()
    np.savez_compressed(buf, map_x=map_x, map_y=map_y, shown=m.shown, content_size=np.array(content_size, np.int64))
    return buf.getvalue()


def write_warp(
    m: WarpMap, out: Path, *, step: int | None = None, content_size: tuple[int, int] | None = None, source: str = ""
) -> dict:
    """Write ``m`` to ``out`` in the format of its suffix, atomically.

    Args:
        m: the warp map.
        out: ``.exr``, ``.obj`` or ``.npz`` (module docstring).
        step: ``.obj`` only: projector pixels between the mesh's vertices (None: ``DEFAULT_STEP``).
        content_size: ``.npz`` only: the content's ``(H, W)``, of the camera frame's aspect (None: the
            camera frame's size).
        source: what the map was made from (a file name), recorded in the file's comments.

    Returns:
        ``format`` (:data:`FORMATS`' name), ``size`` ``(H, W)`` of the projector frame, ``shown`` (the
        share of its pixels that show content); for ``.obj`` also ``step``, ``vertices``, ``triangles`` and
        :func:`~projreg.inference.warpmesh.mesh_error`'s ``error_mean``, ``error_max`` (camera pixels),
        ``covered`` and ``beyond``; for ``.npz`` ``content_size``.

    Raises:
        ProjregError: another suffix, an option the format does not use, a bad ``step`` or
            ``content_size``, or a file that cannot be written: one line naming the option or file.
    """
    suffix = warp_format(out)
    check_options(suffix, step, content_size)
    result = {"format": FORMATS[suffix], "size": m.shown.shape, "shown": float(m.shown.mean())}
    comments = [f"projreg warp {FORMATS[suffix]}" + (f" of {source}" if source else ""), CONVENTION]
    if suffix == ".exr":
        data = encode_stmap(m, "; ".join(comments))
    elif suffix == ".obj":
        step = DEFAULT_STEP if step is None else step
        mesh = grid_mesh(m, step)
        h, w = m.shown.shape
        comments += [
            f"v: projector pixels (x, y, 0) of a {w}x{h} frame, centres at integers, y down; a vertex every "
            f"{step} px, and the last row and column",
            "vt: the content point (u, v) above; f: two triangles a cell, counter-clockwise as the frame shows on "
            "screen",
        ]
        data = obj_text(mesh, comments).encode()
        result |= {
            "step": int(step),
            "vertices": int(used_vertices(mesh).sum()),
            "triangles": 2 * int(mesh.faces.sum()),
        }
        result |= mesh_error(m, mesh)
    else:
        content_size = tuple(m.camera_size if content_size is None else content_size)
        check_aspect(content_size, m.camera_size, "--content-size")
        data = encode_npz(m, content_size)
        result["content_size"] = content_size
    try:
        write_atomic(Path(out), data)
    except ProjsynthError as e:
        raise ProjregError(str(e)) from e
    return result


def export_warp_file(
    flow: Path,
    out: Path,
    *,
    step: int | None = None,
    content_size: tuple[int, int] | None = None,
    coverage: str = "complete",
    min_confidence: float = 0.0,
) -> dict:
    """``projreg warp``: read a flow EXR and write its warp map (:func:`write_warp`), with the coverage
    ``projreg compensate`` gives the same flow and options (the header's ``registered`` and
    ``camera_size``, a flow not written by ``predict`` used where its ``valid`` says).

    Returns:
        :func:`write_warp`'s answer, and ``registered`` and ``as_it_is`` (the pair was not registered:
        the map is the identity, the content projected as it is).
    """
    suffix = warp_format(out)
    guard_outputs([("--out", Path(out))], [("--flow", Path(flow))])
    check_options(suffix, step, content_size)
    try:
        f = read_flow_file(Path(flow))
    except ProjsynthError as e:
        raise ProjregError(str(e)) from e
    registered, in_force = file_coverage(f, coverage, min_confidence)
    camera = stated_camera_size(f.header, flow) or f.valid.shape
    try:
        m = warp_map(
            f.flow,
            claimed=f.valid,
            confidence=f.confidence,
            registered=registered,
            coverage=in_force,
            min_confidence=min_confidence,
            camera_size=camera,
        )
    except ProjregError as e:
        raise ProjregError(f"--flow {flow}: {e}") from e
    result = write_warp(m, out, step=step, content_size=content_size, source=Path(flow).name)
    return result | {"registered": registered, "as_it_is": as_it_is(registered, in_force)}
