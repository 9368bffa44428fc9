import cv2
import numpy as np
from typer.testing import CliRunner

from projreg.cli import app
from projreg.inference.compensate import compensate
from projsynth.dataset.transforms import builtin_table
from projsynth.flow.formats import write_flow_exr
from projsynth.sim.photometric import PAPER_IDENTITY
from projsynth.sim.render import render
from projsynth.sim.rig import make_scene
from projsynth.sim.scene import backward, pixel_grid

H, W = 96, 128


def _texture(seed):
    rng = np.random.default_rng(seed)
    tex = cv2.GaussianBlur(rng.uniform(0, 255, (H, W, 3)).astype(np.float32), (0, 0), 2.0)
    return np.clip((tex - tex.min()) / (tex.max() - tex.min()) * 255, 0, 255).astype(np.uint8)


def test_projecting_the_prewarped_image_shows_the_content():
    cfg = next(c for c in builtin_table().configs if c.family == "sphere_convex" and c.severity == 3)
    scene, _ = make_scene(cfg.family, cfg.geometry, np.random.default_rng(4), (H, W))
    content = _texture(1)
    gt = render(content, np.zeros_like(content), scene, PAPER_IDENTITY, "paper", np.random.default_rng(0))
    prewarped = compensate(content, gt.flow, gt.valid)
    seen = render(prewarped, np.zeros_like(content), scene, PAPER_IDENTITY, "paper", np.random.default_rng(0)).captured
    naive = gt.captured  # projecting the content itself
    # camera pixels lit from well inside the valid projector region
    xy, lit = backward(scene, pixel_grid(H, W))
    inner = cv2.erode(gt.valid.astype(np.uint8), np.ones((5, 5), np.uint8)) > 0
    px, py = np.clip(np.round(xy), 0, [[W - 1], [H - 1]]).astype(int)
    mask = (lit & inner[py, px]).reshape(H, W)
    assert mask.sum() > 2000
    err = np.abs(seen.astype(float) - content)[mask].mean()
    err_naive = np.abs(naive.astype(float) - content)[mask].mean()
    assert err < 4.0 and err < 0.2 * err_naive, (err, err_naive)


def compensate_cli(content, out):
    """``projreg compensate`` of ``content`` through the test's flow (``f.exr`` beside it) into ``out``."""
    return CliRunner().invoke(
        app, ["compensate", "--content", str(content), "--flow", str(content.parent / "f.exr"), "--out", str(out)]
    )


def test_cli_writes_the_projector_image(tmp_path):
    flow = np.zeros((H, W, 2), np.float32)
    flow[..., 0] = 2.0
    valid = np.ones((H, W), bool)
    valid[:, -2:] = False
    write_flow_exr(tmp_path / "f.exr", flow, valid, "x")
    content = _texture(2)
    cv2.imwrite(str(tmp_path / "c.png"), cv2.cvtColor(content, cv2.COLOR_RGB2BGR))
    result = compensate_cli(tmp_path / "c.png", tmp_path / "p.png")
    assert result.exit_code == 0, result.stderr
    lit = f"{(W - 2) / W:.1%}"  # the one-line summary on success
    assert (
        result.stderr == f"{tmp_path / 'p.png'}: {W}x{H} projector image (geometric), content on {lit} of its "
        "pixels, --fill 0 elsewhere\n"
    )
    out = cv2.cvtColor(cv2.imread(str(tmp_path / "p.png")), cv2.COLOR_BGR2RGB)
    np.testing.assert_array_equal(out[:, :-2], content[:, 2:])  # p shows content at p + (2, 0)
    assert (out[:, -2:] == 0).all()
    bad = compensate_cli(tmp_path / "nope.png", tmp_path / "p.png")
    assert bad.exit_code == 2 and "nope.png" in bad.stderr and len(bad.stderr.strip().splitlines()) == 1
    jpg = compensate_cli(tmp_path / "c.png", tmp_path / "p.jpg")
    assert jpg.exit_code == 2 and "--out" in jpg.stderr and "ending in .png" in jpg.stderr
    assert not (tmp_path / "p.jpg").exists()
