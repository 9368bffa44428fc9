"""Judge a flow by what the camera finally sees: compensate, re-render, compare (``bench --compensation``).

For a generated sample, the desired camera view is the sample's projected picture placed in the camera
frame (:func:`projreg.inference.compensate.compensate`'s convention: the picture spans the camera frame). Each
method's flow pre-warps it as the product does by default (:func:`projreg.inference.compensate.prewarp`:
content on every projector pixel whose flow lands in the frame, a pair the method reports as not registered
projected as it is; what the user gets), and once more with content on its claimed pixels only
(``comp_psnr_claimed``, ``comp_ssim_claimed``: the claimed-only coverage, the rest dark; the same as the
default for a method that claims the whole frame); the pre-warped projector image is photographed
through the sample's own scene, photometry and sensor noise (:class:`projsynth.dataset.rerender.Rerenderer`);
so is the pre-warp by the ground-truth flow, and the content projected as it is (the ``uncompensated`` row).

``comp_shown`` is the share of the projector pixels that light the surface inside the frame (the truth's
``valid``) to which a method's default compensation gives content (``comp_shown_min``: the smallest
over the samples). ``comp_psnr`` / ``comp_ssim`` compare a method's camera view with the ground-truth compensation's
view over the **compared region**: camera pixels lit by the projector whose projector pixel is valid
in the ground truth (the surface the true compensation covers), eroded by 2 px so that the
silhouette's antialiasing does not count. Both views carry the same noise, so the difference is the
geometry. SSIM is scikit-image's (Gaussian window, sigma 1.5, on each RGB channel), averaged over
the region; PSNR is over the region's pixels and channels (peak 255). Per row: means over samples.

With ``photometric``, each row also gets ``geo_*`` (the camera's view of the geometric compensation)
and ``photo_*`` (geometric + photometric, :mod:`projreg.inference.radiometric`, calibrated from the camera's
views of a white and a black projection of the same scene, with the devices' response measured from its
views of grey levels or an assumed gamma: :class:`ClosedLoop`) against the **desired view** (the content
spanning the camera frame) up to one global brightness and contrast per channel
(:func:`desired_scores`): PSNR, SSIM and the mean CIEDE2000 colour difference, over the same region.

Example of the region rule: a projector pixel that misses the surface lights no camera pixel, so
errors there cannot be seen and do not count; a flow error inside a flat-coloured area moves flat
colour onto flat colour and costs little PSNR, while the same error on texture costs a lot.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
from skimage.color import deltaE_ciede2000, rgb2lab
from skimage.metrics import structural_similarity

from projsynth.dataset.rerender import Rerenderer, View
from projsynth.errors import ProjsynthError
from projsynth.structured.patterns import make_set
from projsynth.structured.response import Response, fit_response

from ..errors import ProjregError
from ..inference.compensate import compensate, content_mask, lands_in_frame, prewarp
from ..inference.radiometric import calibrate, solve, to_linear
from ..prediction import Prediction, as_prediction

UNCOMPENSATED = "uncompensated"
REGION_ERODE_PX = 2
WHITE_LEVEL = 192  # the calibration's "white": the simulated camera has no exposure to lower, so white would clip
RESPONSES = ("gamma", "measured")  # where the photometric model's device curves come from (ClosedLoop)


class ClosedLoop:
    """Per sample: photograph each method's compensation and score it against the ground truth's
    (and, with ``photometric``, against the desired view: geometric only vs geometric + photometric).

    ``response``: how the photometric model gets the devices' curves (``RESPONSES``): ``gamma``, assumed
    (the simulated devices' own: docs/design.md, "The devices' response, measured"), or ``measured``, fitted
    per sample from the camera's views of the grey levels of ``projsynth patterns --kind response``
    (:mod:`projsynth.structured.response`, with the assumed gamma where the views do not identify the
    camera's exponent; where the fit refuses them, the assumption alone; both counted in :attr:`fits`)."""

    def __init__(self, data: Path, photometric: bool = False, response: str = "gamma"):
        if response not in RESPONSES:
            raise ProjregError(f"--response must be one of {', '.join(RESPONSES)}, got {response!r}")
        try:
            self.rerenderer = Rerenderer(Path(data))
        except ProjsynthError as e:
            raise ProjregError(f"--compensation: {e}") from e
        # the devices' gamma, as a user calibrating that rig would set it: the paper's blend is linear,
        # the physical model has projector gamma 2.2 and a camera response of 2.0-2.4
        self.photometric, self.gamma = photometric, 1.0 if self.rerenderer.plan.blend == "paper" else 2.2
        self.response = response
        self.fits = {"fitted": 0, "identified": 0, "refused": 0}  # measured: the per-sample response fits
        self.last_views: dict[str, np.ndarray] = {}  # the last sample's pictures, for contact sheets

    def _views(self, k: int, images: list[np.ndarray], same_noise: bool = True) -> list[View]:
        try:
            return self.rerenderer.views(k, images, same_noise)
        except ProjsynthError as e:
            raise ProjregError(f"--compensation: sample {k}: {e}") from e

    def score(self, k: int, sample: dict, answers: dict[str, Prediction | np.ndarray]) -> dict[str, dict[str, float]]:
        """``{method: {comp_psnr, comp_ssim, ...}}`` for sample ``k`` (its reader dict), plus ``uncompensated``.

        Args:
            answers: each method's answer (flow ``(H, W, 2)`` in captured pixels, claim, registered; a bare
                flow claims every pixel).
                Each is compensated as ``projreg compensate`` does by default (complete coverage, a pair
                not registered projected as it is); a method that claims only part of the frame is
                also scored with the content on its claimed pixels only (``comp_*_claimed``).
        """
        content = sample["projected"]
        camera = sample["captured"].shape[:2]
        preds = {name: as_prediction(a) for name, a in answers.items()}

        def warp(image: np.ndarray, pred: Prediction, coverage: str = "complete") -> np.ndarray:
            claimed = pred.claimed if coverage == "claimed" else None
            if coverage == "claimed" and not (lands_in_frame(pred.flow, claimed, camera)).any():
                return np.zeros_like(image, shape=(*pred.flow.shape[:2], 3))  # claims nothing: the projector stays dark
            return prewarp(
                image, pred.flow, claimed=claimed, registered=pred.registered, coverage=coverage, camera_size=camera
            )

        # the claimed-only variant differs from the default where a method claims part of the frame or
        # reports the pair as not registered (then it claims nothing): those are photographed again
        partial = [n for n, p in preds.items() if p.claimed is not None and not (p.claimed.all() and p.registered)]
        images = [compensate(content, sample["flow"], sample["valid"], camera_size=camera), content]
        images += [warp(content, p) for p in preds.values()] + [warp(content, preds[n], "claimed") for n in partial]
        views = self._views(k, images)
        region = compared_region(views[0], sample["valid"])
        names = [UNCOMPENSATED, *preds]
        out = {name: view_scores(v.image, views[0].image, region) for name, v in zip(names, views[1:], strict=False)}
        for name, p in preds.items():  # a method that claims the whole frame: its claimed-only view is its default one
            out[name].update({f"{key}_claimed": x for key, x in out[name].items()})
            out[name]["comp_shown"] = surface_shown(p, sample["valid"], camera)
        for name, v in zip(partial, views[len(names) + 1 :], strict=True):
            out[name].update({f"{key}_claimed": x for key, x in view_scores(v.image, views[0].image, region).items()})
        self.last_views = {"truth": views[0].image, **{n: v.image for n, v in zip(names, views[1:], strict=False)}}
        if self.photometric:
            wanted = cv2.resize(content, camera[::-1], interpolation=cv2.INTER_AREA)
            white, black = self._views(k, [np.full_like(content, WHITE_LEVEL), np.zeros_like(content)])
            curves = self._measured(k, content.shape) if self.response == "measured" else None
            model = calibrate(white.image, black.image, self.gamma, WHITE_LEVEL / 255, response=curves)
            needed, _ = solve(wanted, model, region)
            photo = self._views(k, [warp(needed, p) for p in preds.values()])
            corrected = {f"{n}+photometric": v.image for n, v in zip(preds, photo, strict=True)}
            self.last_views.update({"desired": wanted, **corrected})
            for name, geo, ph in zip(names, views[1:], [None, *photo], strict=False):
                out[name].update(desired_scores(geo.image, wanted, region, self.gamma, "geo"))
                none = dict.fromkeys(("photo_psnr", "photo_ssim", "photo_de2000"))
                out[name].update(none if ph is None else desired_scores(ph.image, wanted, region, self.gamma, "photo"))
        return out

    def _measured(self, k: int, shape: tuple[int, ...]) -> Response | None:
        """Sample ``k``'s devices' curves fitted to the camera's views of the grey levels (full white
        included: the fit leaves clipped samples out), each with a noise draw of its own, as photos shot one
        after another (one shared draw would be a per-pixel offset that mimics a linear camera); None where
        the fit refuses the views."""
        steps = make_set("response", shape[:2])
        grey = [np.repeat(img[..., None], 3, axis=2) for img in steps.images()]
        views = self._views(k, grey, same_noise=False)
        photos = np.stack([v.image for v in views]).astype(np.float32) / np.float32(255)
        try:
            curves = fit_response(steps.params["levels"], photos, fallback=self.gamma)
        except ProjsynthError:
            self.fits["refused"] += 1
            return None
        self.fits["fitted"] += 1
        self.fits["identified"] += int(curves.identified)
        return curves


def surface_shown(pred: Prediction, valid: np.ndarray, camera: tuple[int, int]) -> float | None:
    """The share of the projector pixels that light the surface in the frame (the truth's ``valid``) to
    which the default compensation gives content (:func:`~projreg.inference.compensate.content_mask`)."""
    if not valid.any():
        return None
    return float(content_mask(pred.flow, None, pred.registered, "complete", camera)[valid].mean())


def compared_region(truth_view: View, valid: np.ndarray) -> np.ndarray:
    """Camera pixels lit by the projector at a projector pixel valid in the ground truth, eroded."""
    h, w = valid.shape
    x = np.clip(np.rint(truth_view.source[..., 0]), 0, w - 1).astype(np.int64)
    y = np.clip(np.rint(truth_view.source[..., 1]), 0, h - 1).astype(np.int64)
    region = truth_view.lit & valid[y, x]
    k = 2 * REGION_ERODE_PX + 1
    return cv2.erode(region.astype(np.uint8), np.ones((k, k), np.uint8), borderValue=0) > 0


def view_scores(view: np.ndarray, reference: np.ndarray, region: np.ndarray) -> dict[str, float]:
    """PSNR (dB) and mean SSIM of ``view`` against ``reference`` over ``region`` (None: empty region)."""
    if not region.any():
        return {"comp_psnr": None, "comp_ssim": None}
    d = view.astype(np.float64)[region] - reference.astype(np.float64)[region]
    mse = float(np.mean(d * d))
    psnr = 99.0 if mse == 0 else 10 * np.log10(255.0**2 / mse)  # identical views: capped, never inf
    _, ssim = structural_similarity(
        view,
        reference,
        channel_axis=2,
        data_range=255,
        gaussian_weights=True,
        sigma=1.5,
        use_sample_covariance=False,
        full=True,
    )
    return {"comp_psnr": float(psnr), "comp_ssim": float(ssim.mean(axis=2)[region].mean())}


def desired_scores(view: np.ndarray, wanted: np.ndarray, region: np.ndarray, gamma: float, prefix: str) -> dict:
    """``{prefix}_psnr``, ``_ssim`` and ``_de2000`` (mean CIEDE2000) of the camera's view against the desired
    view as this surface can show it at best: per channel, ``a + b * wanted`` in linear light, fitted to
    the view by least squares over ``region`` (a projector cannot make a dark surface as bright as paper,
    so one global brightness and contrast are free). This does not charge a dim view for its lost
    contrast; SSIM's contrast term and the colour difference do, in part."""
    keys = [f"{prefix}_{m}" for m in ("psnr", "ssim", "de2000")]
    if region.sum() < 16:
        return dict.fromkeys(keys)
    v, d = to_linear(view, gamma), to_linear(wanted, gamma)
    fitted = np.empty_like(d)
    for c in range(3):
        A = np.stack([np.ones(region.sum()), d[..., c][region]], 1)
        a, b = np.linalg.lstsq(A, v[..., c][region], rcond=None)[0]
        fitted[..., c] = np.clip(a + b * d[..., c], 0, 1)
    reference = np.clip(np.rint(255 * fitted ** (1 / gamma)), 0, 255).astype(np.uint8)
    scores = view_scores(view, reference, region)
    de = deltaE_ciede2000(rgb2lab(view[region][None]), rgb2lab(reference[region][None]))
    return dict(zip(keys, (scores["comp_psnr"], scores["comp_ssim"], float(de.mean())), strict=True))


COMPENSATION_KEYS = (
    "comp_shown",
    "comp_psnr",
    "comp_ssim",
    "comp_psnr_claimed",
    "comp_ssim_claimed",
    "geo_psnr",
    "photo_psnr",
    "geo_ssim",
    "photo_ssim",
    "geo_de2000",
    "photo_de2000",
)


def compensation_means(scores: list[dict[str, float | None]]) -> dict[str, float | None]:
    """Means over samples of every compensation score present (samples with an empty region skipped)."""
    out = {}
    for key in (k for k in COMPENSATION_KEYS if any(k in s for s in scores)):
        values = [s[key] for s in scores if s.get(key) is not None]
        out[key] = float(np.mean(values)) if values else None
        if key == "comp_shown":  # the worst pair beside the mean: a picture with holes is seen pair by pair
            out["comp_shown_min"] = float(np.min(values)) if values else None
    return out


SHEET_COLUMNS = ("desired", UNCOMPENSATED, "geometric", "geometric + photometric", "ground-truth compensation")


def sheet_row(views: dict[str, np.ndarray], method: str, label: str) -> np.ndarray:
    """One contact-sheet row from :attr:`ClosedLoop.last_views`: desired view | uncompensated photo |
    ``method``'s geometric compensation | geometric + photometric | ground-truth compensation's photo
    (a missing picture is black), with ``label`` over the first picture."""
    ref = views["truth"]
    keys = ("desired", UNCOMPENSATED, method, f"{method}+photometric", "truth")
    row = np.hstack([views.get(k, np.zeros_like(ref)) for k in keys])
    cv2.putText(row, label, (6, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (255, 255, 255), 2, cv2.LINE_AA)
    cv2.putText(row, label, (6, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 1, cv2.LINE_AA)
    return row


def sheet_header(width: int) -> np.ndarray:
    """A white strip naming the columns of :func:`sheet_row` (each ``width`` px wide)."""
    strip = np.full((22, width * len(SHEET_COLUMNS), 3), 255, np.uint8)
    for i, name in enumerate(SHEET_COLUMNS):
        cv2.putText(strip, name, (i * width + 6, 16), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 1, cv2.LINE_AA)
    return strip
