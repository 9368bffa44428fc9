"""docs/results.md is what bench/results_page.py makes of docs/results/, and the generator's rules."""

import importlib.util
import json
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
BENCH = ROOT / "bench"


@pytest.fixture(scope="module")
def gen():
    spec = importlib.util.spec_from_file_location("results_page", BENCH / "results_page.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_committed_page_is_what_the_stored_measurements_give(tmp_path):
    out = tmp_path / "results.md"
    subprocess.run([sys.executable, str(BENCH / "results_page.py"), "--out", str(out)], check=True)
    assert out.read_bytes() == (ROOT / "docs" / "results.md").read_bytes(), (
        "docs/results.md differs from what docs/results/ gives: run make results"
    )


def _meta(name: str, reports: list[str], **extra) -> dict:
    return {
        "set": name,
        "date": "2026-12-01T18:05Z",
        "machine": {
            "cpu": "Test CPU",
            "cores": 2,
            "memory_gib": 24.0,
            "threads": 1,
            "load_average_start": [0.5, 0.4, 0.3],
            "load_average_end": [1.0, 0.9, 0.8],
        },
        "commit": "deadbee",
        "code_commit": "deadbee",
        "dirty": False,
        "weights": {"file": "projreg/weights/reference.pt", "sha256": "0123456789ab"},
        "versions": {"python": "3.11.7", "torch": "2.13.0+cpu", "numpy": "2.4.6", "opencv": "5.0.0"},
        "env": {},
        "wall_s": 90.0,
        "commands": [f"projreg bench --data d --json docs/results/{r}" for r in reports],
        "runs": [{"report": r, "command": "", "label": ""} for r in reports],
        **extra,
    }


def _result(name: str, kind: str, refined: bool, epe: float, claimed: float, ms: float) -> dict:
    pair = {"id": "test-p00000-r0-t057", "epe": epe, "epe_claimed": epe / 2, "claimed": claimed, "registered": True}
    return {
        "name": name,
        "kind": kind,
        "refined": refined,
        "epe": epe,
        "image_epe": epe * 1.1,
        "s0-10": 0.2084,
        "s10-40": 0.37,
        "s40+": None,
        "px1": 0.0773,
        "px3": 0.0206,
        "px5": 0.012,
        "worst_epe": 9.351,
        "worst_id": "test-p00000-r0-t057",
        "claimed": claimed,
        "epe_claimed": epe / 2,
        "unregistered": [],
        "ms_per_pair": ms,
        "pairs": [pair],
    }


def _report(ms: tuple[float, float]) -> dict:
    return {
        "dataset": dict(
            path="d", num_samples=320, evaluated=160, size=[384, 512], camera_size=[384, 512], seed=123, split="test"
        ),
        "reference_model": "/somewhere/reference.pt",
        "results": [
            _result("reference", "model", True, 0.4642, 0.876, ms[0]),
            _result("dis-medium", "baseline", False, 9.0812, 1.0, ms[1]),
        ],
        "versus_baselines": {},
    }


def _write(folder: Path, name: str, data: dict) -> None:
    (folder / name).write_text(json.dumps(data))


def test_a_hand_written_record_is_formatted_and_a_missing_set_is_listed(gen, tmp_path):
    _write(tmp_path, "synthetic.json", _report((7777.7, 43.21)))
    _write(tmp_path, "synthetic.meta.json", _meta("synthetic", ["synthetic.json"]))
    text = gen.page(tmp_path)
    row = next(line for line in text.splitlines() if line.startswith("| `reference` |"))
    # three significant digits, shares in percent, a missing bucket as a dash, the worst pair with its id
    assert row.startswith("| `reference` | 0.464 | 0.511 | 0.208 | 0.370 | – | 7.7 | 2.1 | 87.6 | 0.232 | 9.35 ")
    assert "`test-p00000-r0-t057`" in row
    baseline = next(line for line in text.splitlines() if line.startswith("| `dis-medium` |"))
    assert "| 9.08 |" in baseline and "| all | – |" in baseline
    prose = " ".join(text.split())  # paragraphs are wrapped
    assert "160 of 320 samples, spread evenly over the set; 384 x 512; split test, seed 123." in prose
    assert (
        "commit `deadbee`" in prose and "sha256 `0123456789ab`" in prose and "load average 0.50 at the start" in prose
    )
    # no timing of an evaluation set reaches the page
    assert "7778" not in text and "7777" not in text and "43.2" not in text
    # the sets without a record are listed as such, latency with the file that will hold it
    assert "* [Real pictures](#real-pictures) (not measured)" in text
    assert "Not measured at present: `make results-real`" in text
    assert "`docs/results/latency.json`" in prose
    assert gen.page(tmp_path) == text  # deterministic


def test_a_latency_record_shows_each_method_against_its_peer(gen, tmp_path):
    _write(tmp_path, "latency.json", _report((7777.7, 43.21)))
    _write(tmp_path, "latency.meta.json", _meta("latency", ["latency.json"], peer="dis-medium"))
    text = gen.page(tmp_path)
    assert "| method | ms per pair (median) | x `dis-medium` |" in text
    assert "| `reference` | 7778 | 180 |" in text and "| `dis-medium` | 43.2 | 1.00 |" in text
    assert "Load average at the start 0.50, 0.40, 0.30 (1, 5, 15 min)" in " ".join(text.split())


@pytest.mark.parametrize(
    "value, text", [(None, "–"), (0.0, "0"), (0.46421, "0.464"), (22.69, "22.7"), (115.33, "115"), (2.0, "2.00")]
)
def test_figures_have_three_significant_digits(gen, value, text):
    assert gen.num(value) == text


def test_a_latency_sets_large_pairs_show_predicts_seconds_against_the_baselines(gen, tmp_path):
    def pair(name, epe, claimed):
        return {"pair": name, "epe": epe, "epe_claimed": claimed}

    summary = {
        "pairs": 4,
        "size": "600x800",
        "seed": 2026,
        "predict_seconds": 8.0,
        "claimed_mean": 0.5,
        "not_registered": ["blank"],
        "baseline_seconds": {"sift-ransac": 0.4, "dis-medium": 0.2},
    }
    pairs = [pair("a", 0.2, 0.1), pair("b", 1.0, 0.9), pair("c", 3.0, 1.7), pair("blank", 20.0, None)]
    _write(tmp_path, "latency-large.json", {"summary": summary, "pairs": pairs})
    _write(tmp_path, "latency.meta.json", _meta("latency", ["latency-large.json"], peer="dis-medium"))
    text = gen.page(tmp_path)
    assert "| method | s per pair | x `sift-ransac` | x `dis-medium` |" in text
    assert "| `projreg predict` (one call) | 2.00 | 20.0 | 40.0 |" in text
    assert "| `sift-ransac` | 0.100 | 1.00 | 2.00 |" in text
    prose = " ".join(text.split())
    assert "median pair EPE 2.00 px; worst EPE on a pair's claimed pixels 1.70 px (`c`); not registered: blank" in prose
