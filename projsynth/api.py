"""projsynth's in-memory API: datasets read as arrays, one sample rendered for given pictures, structured
light made and decoded without files (docs/api.md). Nothing here imports torch.

Conventions: images uint8 RGB ``(H, W, 3)`` (patterns and their photos gray ``(H, W)``); a flow is
float32 ``(H, W, 2)`` on the projected grid, forward (projected -> captured), in captured pixels, with
its bool ``(H, W)`` ``valid`` mask; sizes are ``(H, W)``. Errors are :class:`projsynth.ProjsynthError`
with the CLI's one-line messages.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from pathlib import Path

import numpy as np

from .dataset.plan import Sample, make_sample, resolve_plan
from .dataset.shards import ShardReader
from .dataset.transforms import builtin_table
from .errors import ProjsynthError
from .structured.decode import Correspondence, decode, require_decoded, require_in_projector
from .structured.patterns import PatternSet, check_size, make_set
from .structured.response import Response, fit_response


class Dataset(Sequence[dict]):
    """A dataset directory's samples by index, as dicts of arrays (``ShardReader.read``): ``projected``,
    ``captured``, ``flow``, ``valid``, ``params``; a slice gives a list of them, as a list's would. Use it
    in a ``with`` block, or :meth:`close` it."""

    def __init__(self, path: str | Path) -> None:
        if not isinstance(path, str | Path):
            raise TypeError(f"path: expected a dataset directory (str or Path), got {type(path).__name__}")
        if not str(path).strip():
            raise ProjsynthError("path: empty; give a dataset directory")
        self.reader = ShardReader(Path(path))

    def __len__(self) -> int:
        return len(self.reader)

    def __getitem__(self, k: int | slice) -> dict | list[dict]:  # type: ignore[override]
        if isinstance(k, slice):
            return [self[i] for i in range(*k.indices(len(self)))]
        if isinstance(k, bool) or not isinstance(k, int | np.integer):
            raise TypeError(f"sample index: expected an integer or a slice, got {type(k).__name__} {k!r}")
        if not -len(self) <= k < len(self):
            raise IndexError(f"sample {k} of a dataset of {len(self)}")
        return self.reader.read(int(k) % len(self))

    def __iter__(self) -> Iterator[dict]:
        return (self[k] for k in range(len(self)))

    def close(self) -> None:
        self.reader.close()

    def __enter__(self) -> Dataset:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def open_dataset(path: str | Path) -> Dataset:
    """The samples of a ``projsynth gen`` dataset directory (checked like ``projreg bench`` reads it)."""
    return Dataset(path)


def render_pair(
    projected: np.ndarray,
    background: np.ndarray,
    transform: int,
    *,
    seed: int = 0,
    blend: str = "paper",
) -> Sample:
    """One sample of built-in transform ``transform`` (0..159, docs/transforms.md) for the given pictures
    (uint8 RGB of one size: what the projector shows, and what the surface shows beneath it), rendered
    with exact ground truth as ``projsynth gen`` renders its samples (``seed``, ``blend`` as its options)."""
    for name, image in (("projected", projected), ("background", background)):
        image = np.asarray(image)
        if image.dtype != np.uint8 or image.ndim != 3 or image.shape[2] != 3:
            raise ProjsynthError(f"{name}: expected a uint8 RGB array (H, W, 3), got {image.dtype} {image.shape}")
    if projected.shape != background.shape:
        raise ProjsynthError(f"projected {projected.shape} and background {background.shape} differ in size")
    check_size(tuple(projected.shape[:2]), "projected")
    if not isinstance(seed, int | np.integer) or isinstance(seed, bool):
        raise ProjsynthError(f"seed: expected an integer, got {seed!r}")
    count = len(builtin_table().configs)
    if not isinstance(transform, int | np.integer) or isinstance(transform, bool) or not 0 <= transform < count:
        raise ProjsynthError(f"transform: expected one built-in transform id 0..{count - 1}, got {transform!r}")
    plan = resolve_plan(
        size=projected.shape[:2], seed=seed, split="test", pairs=1, transforms=str(transform), blend=blend
    )
    origin = {"natural": ("projected", None), "generated": ("background", None)}
    return make_sample(plan, 0, images=(projected, background, origin))


def make_patterns(kind: str, size: tuple[int, int], **options: int | tuple[int, int]) -> PatternSet:
    """A pattern set (``graycode``, ``dots``, ``opencv-graycode`` or ``response``) for a projector of
    ``size``; ``options`` as ``projsynth patterns``' (``period``, ``shifts``, ``grid``, ``levels``). Its
    ``images()`` are the patterns, uint8 ``(H, W)``, in projection order."""
    unknown = sorted(set(options) - set(OPTIONS))
    if unknown:
        raise ProjsynthError(f"{unknown[0]}: not an option of a pattern set; the options are {', '.join(OPTIONS)}")
    if not isinstance(size, tuple | list | np.ndarray):  # a string would pass tuple() below, character by character
        raise ProjsynthError(f"size: expected (height, width), got {size!r}")
    return make_set(kind, tuple(size), **options)


OPTIONS = ("period", "shifts", "grid", "levels")  # make_patterns' options, as ``projsynth patterns``'


def _check_patterns(patterns: object) -> PatternSet:
    if not isinstance(patterns, PatternSet):
        raise ProjsynthError(f"patterns: expected a PatternSet (make_patterns' answer), got {type(patterns).__name__}")
    return patterns


def fit_device_response(patterns: PatternSet, photos: Sequence[np.ndarray]) -> Response:
    """The camera's and the projector's response curves from the camera's photos of a ``response`` set
    (uint8 or uint16 RGB ``(Hc, Wc, 3)``, in projection order), as ``projsynth response`` fits them from
    files; ``projreg.api.compensate(response=...)`` takes the result."""
    if _check_patterns(patterns).kind != "response":
        raise ProjsynthError(f"a {patterns.kind} set; the response is measured from make_patterns('response', ...)")
    if len(photos) != len(patterns.names):
        raise ProjsynthError(f"{len(photos)} photos for {len(patterns.names)} grey levels")
    return fit_response(patterns.params["levels"], np.stack(_full_scale(photos, "photos", rgb=True)))


def decode_photos(patterns: PatternSet, photos: Sequence[np.ndarray]) -> Correspondence:
    """The camera's photos of ``patterns`` (uint8 or uint16, gray ``(Hc, Wc)`` or RGB, in projection order)
    decoded: ``flow`` and ``valid`` on the projector grid, ``stats``; as ``projsynth decode`` reads them
    from files (grey in [0, 1] at full bit depth, colour as the mean of the channels)."""
    _check_patterns(patterns)
    if isinstance(photos, np.ndarray) or not isinstance(photos, Sequence) or not photos:
        raise ProjsynthError(
            f"photos: expected a non-empty sequence of images, one per pattern, got {type(photos).__name__}"
        )
    gray = np.stack([g if g.ndim == 2 else g[..., :3].mean(axis=-1) for g in _full_scale(photos, "photos")])
    result = decode(patterns, gray)
    if patterns.kind == "opencv-graycode":  # the checks `projsynth decode` makes
        require_in_projector(result, patterns, "patterns")
    require_decoded(result, patterns, gray, "photos")
    return result


def _full_scale(photos: Sequence[np.ndarray], name: str, rgb: bool = False) -> list[np.ndarray]:
    """``photos`` (uint8 or uint16; grey or colour, or ``(Hc, Wc, 3)`` with ``rgb``) as float32 in [0, 1] of
    full scale, all of one size."""
    out = []
    for p in photos:
        p = np.asarray(p)
        channels_ok = p.ndim == 2 or (p.ndim == 3 and p.shape[2] in (1, 3, 4))
        if p.dtype not in (np.uint8, np.uint16) or not channels_ok or (rgb and p.shape[2:] != (3,)) or 0 in p.shape:
            kind = " RGB (H, W, 3)" if rgb else ""
            raise ProjsynthError(f"{name}: expected uint8 or uint16{kind} images, got {p.dtype} {p.shape}")
        out.append(p.astype(np.float32) / np.float32(np.iinfo(p.dtype).max))
    if len({g.shape[:2] for g in out}) > 1:
        raise ProjsynthError(f"{name} of several sizes: {sorted({g.shape[:2] for g in out})}")
    return out


__all__ = [
    "Dataset",
    "Response",
    "decode_photos",
    "fit_device_response",
    "make_patterns",
    "open_dataset",
    "render_pair",
]
