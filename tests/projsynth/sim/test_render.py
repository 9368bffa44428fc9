import numpy as np
import pytest

from projsynth.dataset.transforms import FAMILIES, builtin_table
from projsynth.sim.photometric import PAPER_IDENTITY, sample_bilinear
from projsynth.sim.render import render
from projsynth.sim.rig import make_scene
from projsynth.sim.scene import backward, pixel_grid
from projsynth.utils.ranges import draw

H, W = 96, 128


def _scene(family, seed=0, severity=3):
    cfg = next(c for c in builtin_table().configs if c.family == family and c.severity == severity)
    return make_scene(family, cfg.geometry, np.random.default_rng(seed), (H, W))[0]


def test_sample_bilinear_exact_weights():
    img = np.zeros((4, 5, 4), np.uint8)
    img[1, 2], img[1, 3], img[2, 2], img[2, 3] = 10, 50, 90, 250
    out = sample_bilinear(img, np.array([2.25, 2.0, 3.0]), np.array([1.5, 1.0, 2.0]))
    top, bottom = 10 + 0.25 * 40, 90 + 0.25 * 160
    np.testing.assert_allclose(out[:, 0], [top + 0.5 * (bottom - top), 10, 250], atol=1e-5)


@pytest.mark.parametrize("family", ["planar", "sphere_convex", "wave"])
def test_captured_is_projected_sampled_at_exact_backward_positions(family):
    # a coordinate-encoding projected image: R = x, G = y (exact in uint8 for x, y < 256)
    ys, xs = np.mgrid[0:H, 0:W]
    coded = np.dstack([xs, ys, np.zeros_like(xs)]).astype(np.uint8)
    scene = _scene(family)
    out = render(coded, np.zeros_like(coded), scene, PAPER_IDENTITY, "paper", np.random.default_rng(0))
    xy, lit = backward(scene, pixel_grid(H, W))
    lit = lit.reshape(H, W)
    got = out.captured[lit].astype(float)
    want = xy.T.reshape(H, W, 2)[lit]
    # bilinear interpolation of a linear ramp is exact; the uint8 output rounds to 0.5
    assert np.abs(got[:, :2] - want).max() <= 0.5 + 1e-6
    assert (out.captured[~lit] == 0).all()  # unlit camera pixels show the (black) background only


@pytest.mark.parametrize("family", FAMILIES)
def test_flow_aligns_better_than_any_half_or_one_pixel_shift(family):
    rng = np.random.default_rng(5)
    import cv2

    tex = (
        sum(
            cv2.resize(
                rng.uniform(0, 255, (H // s, W // s, 3)).astype(np.float32), (W, H), interpolation=cv2.INTER_CUBIC
            )
            for s in (2, 4, 8)
        )
        / 3
    )
    proj = np.clip(tex, 0, 255).astype(np.uint8)
    out = render(proj, np.full_like(proj, 90), _scene(family, 1), PAPER_IDENTITY, "paper", rng)
    yv, xv = np.nonzero(out.valid)
    rgba = np.dstack([out.captured, out.captured[..., :1]])

    def err(dx, dy):
        x = np.clip(xv + out.flow[yv, xv, 0] + dx, 0, W - 1)
        y = np.clip(yv + out.flow[yv, xv, 1] + dy, 0, H - 1)
        return np.abs(sample_bilinear(rgba, x, y)[:, :3] - proj[yv, xv]).mean()

    shifts = [(a * s, b * s) for s in (0.5, 1.0) for a, b in ((1, 0), (-1, 0), (0, 1), (0, -1))]
    assert err(0, 0) < min(err(dx, dy) for dx, dy in shifts)


def test_physical_blend_renders_and_records_darker_night():
    cfgs = {c.condition: c for c in builtin_table().configs if c.family == "planar" and c.severity == 1}
    proj = np.full((H, W, 3), 200, np.uint8)
    bg = np.full((H, W, 3), 160, np.uint8)
    means = {}
    for cond in ("night", "daylight"):
        rng = np.random.default_rng(0)
        scene = make_scene("planar", cfgs[cond].geometry, rng, (H, W))[0]
        out = render(proj, bg, scene, draw(rng, cfgs[cond].photometry), "physical", rng)
        means[cond] = out.captured[~out.valid].mean()  # background only: ambient light
    assert means["night"] < means["daylight"]


def _ncc(rgba, x, y, reference):
    """Normalised cross-correlation of ``rgba`` (grey) sampled at ``(x, y)`` with ``reference``."""
    c = sample_bilinear(rgba, x, y)[:, :3].mean(1)
    c, r = c - c.mean(), reference - reference.mean()
    return (c * r).sum() / np.sqrt((c * c).sum() * (r * r).sum())


def test_generated_samples_align_best_at_the_ground_truth():
    """On real samples (full photometry, both roles), the captured image sampled at p + F(p) matches
    the projected image better (normalised cross-correlation) than at any 0.5 or 1 px shift."""
    from projsynth.dataset.plan import make_sample, resolve_plan

    ids = ",".join(str(f * 20 + s * 5 + (f + s) % 5) for f in range(8) for s in range(4))  # every family x severity
    plan = resolve_plan(size=(128, 160), seed=2, split="val", pairs=1, transforms=ids, blend="paper")
    shifts = [(a * s, b * s) for s in (0.5, 1.0) for a, b in ((1, 0), (-1, 0), (0, 1), (0, -1), (1, 1), (-1, -1))]
    checked = 0
    for k in range(plan.num_samples):
        s = make_sample(plan, k)
        h, w = s.valid.shape
        ys, xs = np.nonzero(s.valid)
        u, v = xs + s.flow[ys, xs, 0], ys + s.flow[ys, xs, 1]
        keep = (u >= 1.5) & (u <= w - 2.5) & (v >= 1.5) & (v <= h - 2.5)
        ys, xs, u, v = ys[keep], xs[keep], u[keep], v[keep]
        if len(ys) < 500:
            continue
        rgba = np.dstack([s.captured, s.captured[..., :1]])
        p = s.projected[ys, xs].astype(np.float32).mean(1)
        best_shift = max(_ncc(rgba, u + dx, v + dy, p) for dx, dy in shifts)
        assert _ncc(rgba, u, v, p) > best_shift, (s.id, s.params["transform"]["name"])
        checked += 1
    assert checked >= 50


def test_valid_pixels_keep_a_margin_from_occlusion_and_silhouettes():
    from projsynth.sim.render import EDGE_MARGIN_PX

    scene = _scene("sphere_convex", seed=3, severity=4)
    out = render(
        np.full((H, W, 3), 128, np.uint8),
        np.zeros((H, W, 3), np.uint8),
        scene,
        PAPER_IDENTITY,
        "paper",
        np.random.default_rng(0),
    )
    assert out.stats["invalid_pixels"]["near_edge"] > 0
    from projsynth.sim.scene import forward, pixel_grid

    reason = forward(scene, pixel_grid(H, W)).reason.reshape(H, W)
    edge = np.argwhere((reason & 5) > 0)  # MISS | OCCLUDED
    for y, x in np.argwhere(out.valid)[::17]:
        assert np.abs(edge - (y, x)).max(axis=1).min() > EDGE_MARGIN_PX


def test_sampling_rejects_bad_shapes_and_gives_zero_at_non_finite_positions():
    from projsynth.sim.photometric import sample_where

    img = np.full((4, 5, 4), 7, np.uint8)
    out = sample_bilinear(img, np.array([np.nan, 1.5, np.inf]), np.array([1.0, 1.0, 2.0]))
    assert out[:, 0].tolist() == [0.0, 7.0, 0.0]
    with pytest.raises(ValueError, match="mask"):
        sample_where(img, np.zeros((2, 3)), np.ones(2, bool))
    with pytest.raises(ValueError, match="uint8"):
        sample_bilinear(img[..., :3], np.zeros(1), np.zeros(1))


def test_gaussian_noise_is_standard_normal_and_reproducible():
    from statistics import NormalDist

    from projsynth.sim.photometric import gaussian_noise

    x = gaussian_noise(np.random.default_rng(3), (200, 300, 3))
    assert x.shape == (200, 300, 3) and x.dtype == np.float32
    assert abs(x.mean()) < 0.01 and abs(x.std() - 1) < 0.01
    assert abs(np.mean(x**4) - 3) < 0.05  # kurtosis of a normal, not of a uniform (1.8)
    for q in (0.01, 0.1, 0.5, 0.9, 0.99):  # quantiles within 0.02 sigma of the normal's
        assert abs(np.quantile(x, q) - NormalDist().inv_cdf(q)) < 0.02
    assert np.abs(x).max() < 4.4
    np.testing.assert_array_equal(gaussian_noise(np.random.default_rng(3), (200, 300, 3)), x)
    odd = gaussian_noise(np.random.default_rng(3), (7,))  # sizes that are not a multiple of 4
    np.testing.assert_array_equal(odd, x.ravel()[:7])


# --- the blends by hand: flat images, every parameter away from its identity value ------------------


def _flat_composite(blend, p, *, fg=200, alpha=255, bg=100, lit_rows=None, seed=0, h=8, w=12):
    frame = np.dstack([np.full((h, w, 3), fg, np.uint8), np.full((h, w, 1), alpha, np.uint8)])
    ys, xs = np.mgrid[0:h, 0:w]
    xy = np.stack([xs.ravel(), ys.ravel()]).astype(float)  # identity map: P_w = the flat frame
    lit = np.ones(h * w, bool) if lit_rows is None else (ys < lit_rows).ravel()
    from projsynth.sim.photometric import composite

    return composite(blend, frame, xy, lit, np.full((h, w, 3), bg, np.uint8), p, np.random.default_rng(seed))


PAPER = {"beta": 0.5, "contrast": 0.8, "brightness": 10.0, "gamma": 0.5, "noise_mu": 0.0, "noise_sigma": 0.0}


def test_paper_blend_by_hand():
    # beta*a*(contrast*P + brightness) + (1 - beta*a)*gamma*B = 0.5*(160 + 10) + 0.5*0.5*100 = 110
    assert (_flat_composite("paper", PAPER) == 110).all()
    # a = 128/255: wt = 0.2510; 0.2510*170 + 0.7490*50 = 80.12 -> 80
    assert (_flat_composite("paper", PAPER, alpha=128) == 80).all()
    # unlit camera pixels see the darkened background only: gamma*B = 50
    out = _flat_composite("paper", PAPER, lit_rows=3)
    assert (out[:3] == 110).all() and (out[3:] == 50).all()
    # noise mean mu, then rounding and clipping to uint8
    assert (_flat_composite("paper", PAPER | {"noise_mu": 3.4}) == 113).all()
    assert (_flat_composite("paper", PAPER | {"brightness": 200.0}) == 205).all()  # 0.5*(160 + 200) + 25
    assert (_flat_composite("paper", PAPER | {"brightness": 500.0}) == 255).all()  # 355, clipped
    big = _flat_composite("paper", PAPER | {"noise_sigma": 6.0}, h=200, w=300).astype(float)
    assert abs(big.mean() - 110) < 0.05 and abs(big.std() - np.sqrt(36 + 1 / 12)) < 0.05


PHYSICAL = {
    "ambient": 0.5,
    "power": 0.5,
    "defocus_px": 0.0,
    "gain": 1.0,
    "vignetting": 0.0,
    "shot_noise": 0.0,
    "read_noise": 0.0,
    "response": 2.2,
}


def test_physical_blend_by_hand():
    # full light (ambient + power * a * P_lin = 1) returns the reflectance through the response: B
    assert (_flat_composite("physical", PHYSICAL, fg=255, bg=128) == 128).all()
    # half the light: 255 * ((128/255)^2.2 * 0.5)^(1/2.2) = 128 * 0.5^(1/2.2) = 93.4
    assert (_flat_composite("physical", PHYSICAL | {"power": 0.0}, fg=255, bg=128) == 93).all()
    # gain 1.5 on half the light: 128 * 0.75^(1/2.2) = 112.3
    assert (_flat_composite("physical", PHYSICAL | {"power": 0.0, "gain": 1.5}, fg=255, bg=128) == 112).all()
    # a transparent frame adds no light: the ambient term alone
    assert (_flat_composite("physical", PHYSICAL | {"power": 1.0}, fg=255, bg=128, alpha=0) == 93).all()
    # vignetting: gain * (1 - v * r2), r2 = normalised squared distance from the centre
    h, w, v = 8, 12, 0.4
    out = _flat_composite("physical", PHYSICAL | {"vignetting": v}, fg=255, bg=128, h=h, w=w).astype(float)
    r2 = ((0 - (w - 1) / 2) ** 2 + (0 - (h - 1) / 2) ** 2) / ((w / 2) ** 2 + (h / 2) ** 2)
    assert abs(out[0, 0, 0] - 128 * (1 - v * r2) ** (1 / 2.2)) <= 0.5 + 1e-6
    # a uniform image is unchanged by defocus blur; read noise has the stated deviation
    assert (_flat_composite("physical", PHYSICAL | {"defocus_px": 2.0}, fg=255, bg=128) == 128).all()
    noisy = _flat_composite("physical", PHYSICAL | {"read_noise": 4.0}, fg=255, bg=128, h=200, w=300).astype(float)
    assert abs(noisy.mean() - 128) < 0.05 and abs(noisy.std() - np.sqrt(16 + 1 / 12)) < 0.05
