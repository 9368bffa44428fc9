"""The live loop on moving-rig sequences played in real time (issue 58): registered frames per second,
latency, drops, the tracked EPE against per-frame registration, and what motion prediction does to the
error of the flow each shown frame uses.

Usage: python bench/bench_live.py [--data DIR] [--sequences N] [--quality fast] [--out FILE.json]

Without ``--data`` the sequences are generated first (into a temporary folder): ``projsynth gen --size
384x512 --frames 90 --motion orbit --split test --pairs 1 --seed 11 --transforms 10,50,130`` (a plane,
a convex cylinder and a wave at severity 3, each pair in both roles: six sequences of 3 s at 30 fps).
For each sequence (``--sequences``: the first N):

* its camera frames are written as a lossless video (HuffYUV ``.avi``: 3 ms a frame to decode here,
  FFV1 11, charged to the camera's thread, not the loop's) and played as a camera in real time
  (:class:`projreg.inference.realtime.PlayedVideo`: frame ``k`` arrives at ``k / 30`` s); the content
  on show is the sequence's projected image (it stays fixed over a sequence);
* **live**: ``Registrar.live`` at ``--quality`` (``projreg live``'s default, ``fast``), no prediction:
  frames in, registered, dropped, registered frames per second, latency from arrival to warp (median,
  p95); ``epe_tracked``: the EPE of each registered frame's flow against that frame's truth, pooled
  over the valid pixels of all of them (docs/design.md's convention); ``epe_per_frame``: the same
  frames each registered in full (the network and the refinement, ``Pipeline.register``) offline;
  ``ratio`` = tracked / per frame;
* **shown**: the flow the pre-warp used for each shown frame against the truth of the frame on show
  when it was warped (camera frame ``round(warped * 30)``): ``shown_epe`` without prediction (the
  live run above), and in a second run with ``predict_motion`` on, ``shown_epe`` of the carried-forward
  flows and ``shown_epe_unpredicted`` of the same frames' registered flows (the paired comparison).

The machine's load average (``os.getloadavg``) is recorded before and after: the loop is real time, so
its rate depends on what else runs.

``--out`` writes the JSON: ``command``, ``date``, ``load_average`` (``before``, ``after``: 1, 5, 15
minutes), ``cpus``, ``data`` (``path``, ``size``, ``frames``, ``motion``, ``fps``), ``quality``,
``sequences`` (one object per sequence: ``sequence``, ``transform``, ``live`` (the loop's summary:
``frames_in``, ``registered``, ``dropped``, ``fps``, ``latency_ms`` {``median``, ``p95``, ``max``},
``steps``, ``seconds``, plus ``epe_tracked``, ``epe_per_frame``, ``ratio``, ``shown_epe``), ``predicted``
(its summary plus ``shown_epe``, ``shown_epe_unpredicted``)), and ``pooled`` (over all sequences:
``fps`` and latency ``median``/``p95`` of all frames, ``frames_in``, ``registered``, ``dropped``,
``epe_tracked``, ``epe_per_frame``, ``ratio``, ``shown_epe``, ``shown_epe_predicted``,
``shown_epe_unpredicted``).
"""

from __future__ import annotations

import argparse
import datetime
import json
import os
import sys
import tempfile
from pathlib import Path

import numpy as np

from projreg.api import Registrar
from projreg.inference.realtime import PlayedVideo
from projreg.inference.video import VideoWriter
from projsynth.api import open_dataset
from projsynth.dataset.generate import generate
from projsynth.dataset.plan import resolve_plan

GENERATED = {"size": (384, 512), "frames": 90, "motion": "orbit", "seed": 11, "transforms": "10,50,130"}
FPS = 30.0  # the simulator's frame rate: the camera plays at it


class Pooled:
    """End-point errors pooled over the valid pixels of several frames."""

    def __init__(self) -> None:
        self.total, self.pixels = 0.0, 0

    def add(self, flow: np.ndarray, truth: np.ndarray, valid: np.ndarray) -> None:
        self.total += float(np.linalg.norm(flow - truth, axis=-1)[valid].sum())
        self.pixels += int(valid.sum())

    def merge(self, other: Pooled) -> None:
        self.total, self.pixels = self.total + other.total, self.pixels + other.pixels

    def value(self) -> float | None:
        return self.total / self.pixels if self.pixels else None


def sequences(data: Path) -> dict[str, list[int]]:
    """Sample indices of each sequence, in frame order."""
    ds = open_dataset(data)
    out: dict[str, list[int]] = {}
    for k in range(len(ds)):
        out.setdefault(ds[k]["params"]["sequence"], []).append(k)
    return out


def run_sequence(registrar: Registrar, data: Path, name: str, indices: list[int], work: Path) -> dict:
    ds = open_dataset(data)
    frames = [ds[k] for k in indices]
    video = work / f"{name}.avi"
    with VideoWriter(video, FPS) as writer:
        for s in frames:
            writer.write(s["captured"])
    content = frames[0]["projected"]
    live = registrar.live(PlayedVideo(video, fps=FPS), content)
    tracked, shown, registered = Pooled(), Pooled(), []
    for f in live:
        s = frames[f.index]
        tracked.add(f.registration.flow, s["flow"], s["valid"])
        on_show = frames[min(round(f.warped * FPS), len(frames) - 1)]
        shown.add(f.flow, on_show["flow"], on_show["valid"])
        registered.append(f.index)
    per_frame = Pooled()
    for k in registered:
        s = frames[k]
        per_frame.add(registrar.register(s["projected"], s["captured"]).flow, s["flow"], s["valid"])
    predicted_live = registrar.live(PlayedVideo(video, fps=FPS), content, predict_motion=True)
    predicted, unpredicted = Pooled(), Pooled()
    for f in predicted_live:
        on_show = frames[min(round(f.warped * FPS), len(frames) - 1)]
        predicted.add(f.flow, on_show["flow"], on_show["valid"])
        unpredicted.add(f.registration.flow, on_show["flow"], on_show["valid"])
    ratio = None if not per_frame.value() else tracked.value() / per_frame.value()
    return {
        "sequence": name,
        "transform": frames[0]["params"].get("transform_id"),
        "live": live.summary()
        | {
            "epe_tracked": tracked.value(),
            "epe_per_frame": per_frame.value(),
            "ratio": ratio,
            "shown_epe": shown.value(),
            "latencies": [r["latency_ms"] for r in live.records()],
        },
        "predicted": predicted_live.summary()
        | {
            "shown_epe": predicted.value(),
            "shown_epe_unpredicted": unpredicted.value(),
            "latencies": [r["latency_ms"] for r in predicted_live.records()],
        },
        "_pools": (tracked, per_frame, shown, predicted, unpredicted),
    }


def pooled(rows: list[dict]) -> dict:
    pools = [Pooled() for _ in range(5)]
    for row in rows:
        for total, part in zip(pools, row.pop("_pools"), strict=True):
            total.merge(part)
    latencies = [ms for row in rows for ms in row["live"]["latencies"]]
    seconds = sum(row["live"]["seconds"] for row in rows)
    tracked, per_frame, shown, predicted, unpredicted = (p.value() for p in pools)
    return {
        "frames_in": sum(row["live"]["frames_in"] for row in rows),
        "registered": sum(row["live"]["registered"] for row in rows),
        "dropped": sum(row["live"]["dropped"] for row in rows),
        "fps": sum(row["live"]["registered"] for row in rows) / seconds,
        "latency_ms": {"median": float(np.median(latencies)), "p95": float(np.percentile(latencies, 95))},
        "epe_tracked": tracked,
        "epe_per_frame": per_frame,
        "ratio": tracked / per_frame if per_frame else None,
        "shown_epe": shown,
        "shown_epe_predicted": predicted,
        "shown_epe_unpredicted": unpredicted,
    }


def table(rows: list[dict], total: dict, load: dict) -> str:
    def f(x: float | None, digits: int = 3) -> str:
        return "–" if x is None else f"{x:.{digits}g}"

    lines = [
        f"Live loop, {total['registered']} registered of {total['frames_in']} frames in; load average before "
        f"{load['before'][0]:.2f}, after {load['after'][0]:.2f} (1 min), {os.cpu_count()} CPUs.",
        "",
        "| sequence | fps | latency median / p95 (ms) | in / registered / dropped | EPE tracked | EPE per frame "
        "| ratio | shown EPE | shown EPE, predicted (same frames unpredicted) |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for row in rows:
        live, pred = row["live"], row["predicted"]
        lat = live["latency_ms"] or {"median": None, "p95": None}
        lines.append(
            f"| {row['sequence']} | {live['fps']:.1f} | {f(lat['median'])} / {f(lat['p95'])} | "
            f"{live['frames_in']} / {live['registered']} / {live['dropped']} | {f(live['epe_tracked'])} | "
            f"{f(live['epe_per_frame'])} | {f(live['ratio'])} | {f(live['shown_epe'])} | "
            f"{f(pred['shown_epe'])} ({f(pred['shown_epe_unpredicted'])}) |"
        )
    t = total
    lines.append(
        f"| **all** | {t['fps']:.1f} | {f(t['latency_ms']['median'])} / {f(t['latency_ms']['p95'])} | "
        f"{t['frames_in']} / {t['registered']} / {t['dropped']} | {f(t['epe_tracked'])} | {f(t['epe_per_frame'])} "
        f"| {f(t['ratio'])} | {f(t['shown_epe'])} | {f(t['shown_epe_predicted'])} ({f(t['shown_epe_unpredicted'])}) |"
    )
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, help="a `projsynth gen --frames` dataset (default: generated)")
    parser.add_argument("--sequences", type=int, default=None, help="the first N sequences (default: all)")
    parser.add_argument("--quality", default="fast", help="fast, balanced or accurate (default: fast)")
    parser.add_argument("--model", default=None, help="checkpoint (default: the shipped reference model)")
    parser.add_argument("--out", type=Path, help="write the figures as JSON")
    args = parser.parse_args()
    load = {"before": list(os.getloadavg())}
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        data = args.data
        if data is None:
            data = work / "data"
            g = GENERATED
            plan = resolve_plan(
                size=g["size"],
                seed=g["seed"],
                split="test",
                pairs=1,
                transforms=g["transforms"],
                blend="paper",
                frames=g["frames"],
                motion=g["motion"],
            )
            generate(plan, data, shard_size=g["frames"])
        registrar = Registrar(args.model, quality=args.quality)
        found = sequences(data)
        names = sorted(found)[: args.sequences]
        rows = []
        for name in names:
            rows.append(run_sequence(registrar, data, name, found[name], work))
            print(f"{name}: {rows[-1]['live']['fps']:.1f} fps", file=sys.stderr)
        load["after"] = list(os.getloadavg())
        total = pooled(rows)
        ds = open_dataset(data)
        first = ds[found[names[0]][0]]["params"]
        info = {
            "path": None if args.data is None else str(args.data),
            "generated": None if args.data is not None else GENERATED | {"size": list(GENERATED["size"])},
            "size": list(ds[0]["projected"].shape[:2]),
            "frames": len(found[names[0]]),
            "motion": first.get("motion", {}).get("preset") if isinstance(first.get("motion"), dict) else None,
            "fps": FPS,
        }
    print(table(rows, total, load))
    if args.out:
        for row in rows:
            for run in ("live", "predicted"):
                row[run].pop("latencies")
        report = {
            "command": " ".join([Path(sys.argv[0]).name, *sys.argv[1:]]),
            "date": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
            "load_average": load,
            "cpus": os.cpu_count(),
            "data": info,
            "quality": args.quality,
            "sequences": rows,
            "pooled": total,
        }
        args.out.write_text(json.dumps(report, indent=1) + "\n")


if __name__ == "__main__":
    main()
