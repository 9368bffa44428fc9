"""bench/external_rig.py: its truth (checked against a rendered dot, not against projsynth) and its report."""

import importlib.util
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

BENCH = Path(__file__).resolve().parents[1] / "bench"


@pytest.fixture(scope="module")
def rig():
    pytest.importorskip("skimage")
    spec = importlib.util.spec_from_file_location("external_rig", BENCH / "external_rig.py")
    module = importlib.util.module_from_spec(spec)
    sys.modules["external_rig"] = module  # its dataclass looks its module up by name
    spec.loader.exec_module(module)
    return module


@pytest.mark.parametrize("index", range(4))  # bend, dome, lens, fold
def test_truth_puts_a_projected_dot_where_the_camera_sees_it(rig, index):
    h, w = 120, 160
    dots = [(40, 50), (85, 100), (60, 125)]
    projected = np.zeros((h, w, 3), np.uint8)
    for y, x in dots:
        projected[y - 1 : y + 2, x - 1 : x + 2] = 255  # a 3 x 3 white square centred on (x, y)
    force = {"albedo": "plain", "response": "linear", "ambient": 0.0}
    pair = rig.render("dots", projected, index, seed=5, force=force)
    assert pair.settings["shape"] == rig.SHAPES[index]
    light = pair.captured[..., 1].astype(np.float64)
    light = np.where(light > 40, light, 0)  # the dots, above the noise
    yy, xx = np.mgrid[0:h, 0:w]
    inside = [3 < pair.flow[y, x, 0] + x < w - 4 and 3 < pair.flow[y, x, 1] + y < h - 4 for y, x in dots]
    seen = [d for d, ok in zip(dots, inside, strict=True) if ok]
    assert seen, "every dot left the camera frame"
    for y, x in seen:
        u, v = pair.flow[y, x]
        near = (np.abs(xx - (x + u)) < 6) & (np.abs(yy - (y + v)) < 6)
        weight = light * near
        centroid = np.array([(weight * xx).sum(), (weight * yy).sum()]) / weight.sum()
        assert np.abs(centroid - (x + u, y + v)).max() < 0.35, (index, centroid, (x + u, y + v))


def test_invert_closes_the_forward_map(rig):
    rng = np.random.default_rng(0)
    for shape in rig.SHAPES:
        bend = rig.surface_map(shape, rng, 90, 120)
        q = rng.uniform(0, 100, (50, 2))
        p = rig.invert(bend, q, q.copy())
        assert np.abs(bend(p) - q).max() < 1e-4


def test_a_small_run_reports_every_pair(rig, tmp_path):
    """End to end, as the docs run it: render, ``projreg predict`` on the folders, score, JSON."""
    out = tmp_path / "ext"
    cmd = [
        sys.executable,
        str(BENCH / "external_rig.py"),
        "--out",
        str(out),
        "--size",
        "96x128",
        "--limit",
        "2",
        "--json",
        str(tmp_path / "r.json"),
        "--albedo",
        "stripes",
    ]
    subprocess.run(cmd, check=True, capture_output=True, text=True)
    report = json.loads((tmp_path / "r.json").read_text())
    assert [r["pair"] for r in report["pairs"]] == ["astronaut", "coffee"]
    for r in report["pairs"]:
        assert r["albedo"] == "stripes" and 0 <= r["claimed"] <= 1
        assert r["sift-ransac"] >= 0 and r["dis-medium"] >= 0 and r["zero_flow"] > 0
        if r["ratio"] is not None:
            assert r["ratio"] == pytest.approx(
                r["epe_claimed"] / min(r["sift-ransac_on_claimed"], r["dis-medium_on_claimed"])
            )
    assert report["summary"]["pairs"] == 2 and report["summary"]["force"] == {"albedo": "stripes"}
    timed = report["summary"]["baseline_seconds"]  # each baseline's time over the pairs, for the latency page
    assert set(timed) == {"sift-ransac", "dis-medium"} and all(t > 0 for t in timed.values())
    assert timed["sift-ransac"] == pytest.approx(sum(r["sift-ransac_seconds"] for r in report["pairs"]))
