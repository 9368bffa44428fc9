"""Re-measure one evaluation set of docs/results.md and store its figures under docs/results/.

Usage: python bench/record.py SET [--threads N] [--dry-run]      (``make results-SET``, then ``make results``)
       python bench/record.py --all                               (``make results-all``: every set but latency)
       python bench/record.py --list

Each set (``SETS`` below) is a fixed list of commands at sizes chosen so that the set takes at most
about 15 min on one core of the 2-core CI VM. They run one after the other from the repository
root, with ``OMP_NUM_THREADS``, ``NUMBA_NUM_THREADS`` and ``OPENCV_FOR_THREADS_NUM`` set to
``--threads`` (default 1: torch, numba and OpenCV on one core each, so that a shared machine keeps a
core free); datasets go to ``build/results/SET/`` (deleted first; git-ignored). The set's last
commands write their reports straight into ``docs/results/`` (``projreg bench --json``,
``bench/bench_decode.py --json``, ``bench/external_rig.py --json``: each file is that command's
exact output), then ``docs/results/SET.meta.json`` records how they were made:

* ``commands``: every command, as typed in the project's virtualenv; ``runs``: which command wrote
  which report, and its label on the page;
* ``date`` (UTC), ``wall_s`` (the whole set, every command with its wall time in ``steps``);
* ``machine``: CPU model, cores, memory, ``threads`` used, the load average at the start and the end
  (``os.getloadavg``: 1, 5 and 15 min);
* ``commit`` (``git rev-parse --short HEAD``), ``code_commit`` (the last commit that changed
  ``projsynth/`` or ``projreg/``) and ``dirty`` (uncommitted changes to tracked files there or in ``bench/``);
* ``weights``: the reference model file and the first 12 hex digits of its sha256;
* ``versions``: python, torch, numpy, OpenCV.

A command that fails leaves the set's files under docs/results/ as they were. ``latency`` is the one
set meant for an idle machine (run it with ``--threads`` equal to the cores): the page shows its
``ms_per_pair`` and nothing else's.
"""

from __future__ import annotations

import argparse
import datetime
import hashlib
import json
import os
import platform
import re
import shlex
import shutil
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
RESULTS = Path("docs/results")
WEIGHTS = Path("projreg/weights/reference.pt")
THREAD_VARS = ("OMP_NUM_THREADS", "NUMBA_NUM_THREADS", "OPENCV_FOR_THREADS_NUM")


def make_var(name: str) -> str:
    """A ``NAME := value`` variable of the Makefile (the transform lists and baselines its targets use)."""
    m = re.search(rf"^{name} :?= *(.+)$", (ROOT / "Makefile").read_text(), re.M)
    if m is None:
        raise SystemExit(f"record: the Makefile defines no {name}")
    return m.group(1).strip()


SPREAD32 = make_var("SPREAD32")
BASELINES = make_var("BASELINES")


@dataclass(frozen=True)
class Run:
    """A command that writes one report (``docs/results/REPORT``); ``label`` names its table on the page."""

    report: str
    command: str
    label: str = ""


@dataclass(frozen=True)
class ResultSet:
    """An evaluation set: ``prepare`` makes its data, each of ``runs`` writes a report.

    ``kind`` says how the page reads the reports: ``bench`` (``projreg bench --json``), ``decode``
    (``bench/bench_decode.py``), ``external`` (``bench/external_rig.py``), ``warp``
    (``bench/bench_warp.py``), ``live`` (``bench/bench_live.py``, timed) or ``latency`` (a bench report of
    which only the timings are shown, each beside its ratio to the method ``peer``).
    ``about`` is the set's paragraph on the page.
    """

    name: str
    title: str
    kind: str
    about: str
    prepare: tuple[str, ...]
    runs: tuple[Run, ...]
    peer: str = ""


def _bench(data: str, report: str, options: str) -> str:
    return f"projreg bench --data {data} {options} --json {RESULTS / report} --quiet"


def _gen(out: str, options: str) -> str:
    return f"projsynth gen --out {out} {options} --workers 1 --quiet"


_B = "build/results"
SETS = (
    ResultSet(
        "synthetic",
        "Synthetic test split",
        "bench",
        "A fresh test split: the test split's source images (never used in training), one pair in both "
        "roles over all 160 transforms of the table.",
        (_gen(f"{_B}/synthetic", "--split test --pairs 1 --seed 123"),),
        (
            Run(
                "synthetic.json",
                _bench(f"{_B}/synthetic", "synthetic.json", f"--baselines {BASELINES} --refine both --limit 160"),
            ),
        ),
    ),
    ResultSet(
        "real",
        "Real pictures",
        "bench",
        "Pictures the model never saw: scikit-image's photographs and its artworks "
        "(`bench/real_sources.py`: 12 and 7), paired by `projsynth gen --split all` over the 32 transforms of "
        "the Makefile's `SPREAD32` (every family and severity once).",
        (
            f"python bench/real_sources.py --out {_B}/real/sources",
            _gen(
                f"{_B}/real/data",
                f"--natural {_B}/real/sources/natural --generated {_B}/real/sources/generated "
                f"--split all --seed 5 --transforms {SPREAD32}",
            ),
        ),
        (
            Run(
                "real.json",
                _bench(f"{_B}/real/data", "real.json", f"--baselines {BASELINES} --refine both --limit 112"),
            ),
        ),
    ),
    ResultSet(
        "hard",
        "Adversarial pictures",
        "bench",
        "Pictures a registration tool should refuse or survive (`bench/hard_sources.py`: content on part "
        "of the frame, near-uniform, repetitive and striped pictures), rendered with the physical model "
        "(non-linear camera response, ambient light up to daylight) over the 32 transforms of `SPREAD32`. "
        "Most pairs defeat every method; what matters is what a method claims.",
        (
            f"python bench/hard_sources.py --out {_B}/hard/sources",
            _gen(
                f"{_B}/hard/data",
                f"--natural {_B}/hard/sources/natural --generated {_B}/hard/sources/generated "
                f"--split all --seed 11 --blend physical --transforms {SPREAD32}",
            ),
        ),
        (
            Run(
                "hard.json", _bench(f"{_B}/hard/data", "hard.json", f"--baselines {BASELINES} --refine both --limit 48")
            ),
        ),
    ),
    ResultSet(
        "decode",
        "Structured-light decoding",
        "decode",
        "`projsynth`'s structured-light decoder on the virtual rig (`bench/bench_decode.py`): every 4th "
        "transform of the table photographed through `projsynth.structured.capture` (projector 480 x 640, camera "
        "600 x 800, seed 0), decoded, and compared with the simulator's exact forward map. Coverage: the "
        "share of projector pixels (dots: dot centres) landing valid in the camera frame that were "
        'decoded; errors in projector px over the decoded pixels; "valid where truth is not": decoded '
        "pixels whose ray misses the surface, is occluded or leaves the camera frame.",
        (),
        (Run("decode.json", f"python bench/bench_decode.py --every 4 --json {RESULTS / 'decode.json'}"),),
    ),
    ResultSet(
        "compensation",
        "Closed-loop compensation",
        "bench",
        "Each method's flow used to compensate the projection, judged by what the camera then sees "
        "(`projreg bench --compensation --photometric`, docs/projreg-cli.md): two fresh test splits, one "
        "built-in pair over the 32 transforms of `SPREAD32`, one with the paper's blend and one with the "
        "physical camera model. `comp` scores the camera's view of each method's compensation as `projreg "
        "compensate` makes it by default (content wherever the flow lands in the frame, a pair the method does "
        "not register projected as it is) against the ground-truth compensation's view; `claimed only` the same "
        "with content on the claimed pixels alone; `content on surface` the share of the projector pixels that "
        "light the surface to which the default gives content (the worst pair in brackets); `geo` / `photo` "
        "compare geometric against geometric + photometric compensation with the desired view (PSNR dB, SSIM, "
        "CIEDE2000). `+photos` rows: the model registering the capture with the surface divided out by the "
        "rig's white and black photos (`bench --photos`).",
        (
            _gen(f"{_B}/compensation/paper", f"--split test --pairs 1 --seed 321 --transforms {SPREAD32}"),
            _gen(
                f"{_B}/compensation/physical",
                f"--split test --pairs 1 --seed 322 --blend physical --transforms {SPREAD32}",
            ),
        ),
        tuple(
            Run(
                f"compensation-{blend}.json",
                _bench(
                    f"{_B}/compensation/{blend}",
                    f"compensation-{blend}.json",
                    "--baselines dis-medium,sift-ransac --compensation --photometric --photos --limit 32",
                ),
                f"{blend} blend",
            )
            for blend in ("paper", "physical")
        ),
    ),
    ResultSet(
        "tracking",
        "Tracking moving-rig sequences",
        "bench",
        "Sequences of a slowly moving rig (`projsynth gen --frames 8`, motion `hover`): three transforms "
        "(lens, concave sphere, bumps) x two roles, 8 frames each. `+track` rows "
        "register each frame from the previous frame's flow (the first in full); jitter is the mean "
        "frame-to-frame change of the error vector.",
        (_gen(f"{_B}/tracking", "--split test --pairs 1 --seed 2611 --transforms 26,105,148 --frames 8"),),
        (Run("tracking.json", _bench(f"{_B}/tracking", "tracking.json", "--track --baselines dis-medium")),),
    ),
    ResultSet(
        "external",
        "External rig (pairs not made by projsynth)",
        "external",
        "Pairs rendered by a rig written from scratch in `bench/external_rig.py` (numpy and OpenCV only): "
        "scikit-image's pictures (14 full frame, 3 on the left 45 % of the frame, one almost blank page) "
        "after a homography and a bend, dome, lens or fold, on a painted, plaster or brick wall, through "
        "gamma, S-curve or clipped camera responses; 384 x 512; the third run a plaid cloth whose pattern rivals "
        "the projected picture's; the last two the striped sheet on two more draws of the rig's jitter (the "
        "refinement's rules were measured on the first). The pipeline is `projreg predict` on the "
        "two folders, as a user runs it, against SIFT + RANSAC and DIS medium on the same pairs. The "
        "script reports per-pair means, no pooled EPE.",
        (),
        (
            Run(
                "external-rotating.json",
                f"python bench/external_rig.py --out {_B}/external/rotating "
                f"--json {RESULTS / 'external-rotating.json'}",
                "settings rotating per pair, seed 2026",
            ),
            Run(
                "external-stripes.json",
                f"python bench/external_rig.py --out {_B}/external/stripes --shape bend "
                f"--albedo stripes --response gamma --ambient 0 --json {RESULTS / 'external-stripes.json'}",
                "a bent sheet with painted stripes, gamma response, dark room",
            ),
            Run(
                "external-plaid.json",
                f"python bench/external_rig.py --out {_B}/external/plaid --albedo plaid --ambient 0.25 "
                f"--json {RESULTS / 'external-plaid.json'}",
                "a plaid cloth, room light a quarter of the projector's white",
            ),
            *(
                Run(
                    f"external-stripes-{seed}.json",
                    f"python bench/external_rig.py --out {_B}/external/stripes-{seed} --seed {seed} --shape bend "
                    f"--albedo stripes --response gamma --ambient 0 --json {RESULTS / f'external-stripes-{seed}.json'}",
                    f"the striped sheet again, another draw of the rig's jitter (seed {seed})",
                )
                for seed in (2027, 2028)
            ),
        ),
    ),
    ResultSet(
        "warp",
        "Warp maps for show software",
        "warp",
        "`projreg warp`'s files applied as show software applies them (`bench/bench_warp.py`, docs/show.md): "
        "the STMap (`.exr`) remapped, each mesh (`.obj`, a vertex every 8, 16 or 32 projector pixels) "
        "rasterised with its texture coordinates linear over each triangle, the `cv2.remap` maps (`.npz`), "
        "against `projreg compensate`'s image of the same flow; the flows `projreg predict`'s on pictures the "
        "model never saw (`bench/real_sources.py`) under seven transforms of the table.",
        (
            f"python bench/real_sources.py --out {_B}/warp/sources",
            _gen(
                f"{_B}/warp/data",
                f"--natural {_B}/warp/sources/natural --generated {_B}/warp/sources/generated --split all "
                "--pairs 1 --seed 5 --transforms 12,27,48,85,112,127,148",
            ),
        ),
        (Run("warp.json", f"python bench/bench_warp.py --data {_B}/warp/data --out {RESULTS / 'warp.json'}"),),
    ),
    ResultSet(
        "live",
        "The live loop",
        "live",
        "`projreg live` on moving-rig sequences played as a camera in real time (`bench/bench_live.py`, "
        "docs/show.md): six orbiting-rig sequences of 90 frames at 384 x 512 (a plane, a convex cylinder and a "
        "wave, each pair in both roles), each a lossless video played at 30 fps, the content the sequence's "
        "projected image, `--quality fast` (`live`'s default). Frames that arrive while one is registered are "
        "dropped; latency runs from a frame's arrival to its pre-warped frame; EPEs pool the valid pixels of the "
        "frames registered, tracked against registering each of them in full; the shown EPE is the flow each "
        "pre-warp used against the truth of the camera frame on show when it was warped, without and with "
        "`--predict-motion`. To be measured on an idle machine, with the threads stated.",
        (),
        (Run("live.json", f"python bench/bench_live.py --out {RESULTS / 'live.json'}"),),
    ),
    ResultSet(
        "latency",
        "Latency",
        "latency",
        "Milliseconds per 384 x 512 pair (median over the pairs, after one untimed warm-up pair; "
        "`ms_per_pair` of `projreg bench`), every method in the same run on the same pairs, so the ratios "
        "hold where the absolute times drift; and seconds per 600 x 800 pair of `projreg predict` on two "
        "folders as a user runs it (`bench/external_rig.py`: one call, start-up and files included) beside "
        "the baselines' time on the same pairs. The 32 pairs are 16 test-split picture pairs each way round "
        "under the 32 transforms of `SPREAD32`, so that no two pairs share a projected image, as in a fresh "
        "split: the refinement builds a projected image's side once and reuses it for the next pair of that "
        "image, which a set of one picture (this set until 2026-12-03) hid. To be measured on an idle "
        "machine, with the threads stated.",
        (_gen(f"{_B}/latency", f"--split test --pairs 16 --seed 123 --transforms {SPREAD32}"),),
        (
            Run(
                "latency.json",
                _bench(f"{_B}/latency", "latency.json", f"--baselines {BASELINES} --refine both --limit 32"),
                "--quality balanced (the default)",
            ),
            *(
                Run(
                    f"latency-{q}.json",
                    _bench(
                        f"{_B}/latency",
                        f"latency-{q}.json",
                        f"--quality {q} --baselines dis-medium,sift-ransac --refine both --limit 32",
                    ),
                    f"--quality {q}",
                )
                for q in ("accurate", "fast")
            ),
            Run(
                "latency-large.json",
                f"python bench/external_rig.py --out {_B}/latency/large --size 600x800 "
                f"--json {RESULTS / 'latency-large.json'}",
                "600 x 800 pairs, `projreg predict` on two folders",
            ),
        ),
        "dis-medium",
    ),
)
BY_NAME = {s.name: s for s in SETS}


def _git(*args: str) -> str:
    return subprocess.run(["git", *args], cwd=ROOT, check=True, capture_output=True, text=True).stdout.strip()


def _cpu_model() -> str:
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or platform.machine()


def _memory_gib() -> float | None:
    try:
        kib = int(re.search(r"MemTotal:\s+(\d+)", Path("/proc/meminfo").read_text()).group(1))
    except (OSError, AttributeError):
        return None
    return round(kib / 2**20, 1)


def _load() -> list[float]:
    return [round(x, 2) for x in os.getloadavg()]


def _versions() -> dict[str, str]:
    code = "import sys, cv2, numpy, torch; print(sys.version.split()[0], torch.__version__, numpy.__version__, "
    code += "cv2.__version__)"
    out = subprocess.run([sys.executable, "-c", code], check=True, capture_output=True, text=True).stdout.split()
    return dict(zip(("python", "torch", "numpy", "opencv"), out, strict=True))


def provenance(threads: int) -> dict:
    """Everything the page states about a run but the figures: machine, load, code, weights, versions."""
    return {
        "date": datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%dT%H:%MZ"),
        "machine": {
            "cpu": _cpu_model(),
            "cores": os.cpu_count(),
            "memory_gib": _memory_gib(),
            "threads": threads,
            "load_average_start": _load(),
        },
        "commit": _git("rev-parse", "--short", "HEAD"),
        "code_commit": _git("log", "-1", "--format=%h", "--", "projsynth", "projreg"),
        "dirty": bool(_git("status", "--porcelain", "--untracked-files=no", "--", "projsynth", "projreg", "bench")),
        "weights": {
            "file": str(WEIGHTS),
            "sha256": hashlib.sha256((ROOT / WEIGHTS).read_bytes()).hexdigest()[:12],
        },
        "versions": _versions(),
        "env": dict.fromkeys(THREAD_VARS, str(threads)),
    }


def argv(command: str) -> list[str]:
    """A command as written on the page -> what to execute: the virtualenv's tools and interpreter."""
    words = shlex.split(command)
    if words[0] == "python":
        words[0] = sys.executable
    elif words[0] in ("projsynth", "projreg"):
        words[0] = str(Path(sys.executable).with_name(words[0]))
    return words


def record(rs: ResultSet, threads: int, dry_run: bool = False) -> dict | None:
    """Run the set's commands and write its reports and ``SET.meta.json``; returns the meta record."""
    commands = [*rs.prepare, *(r.command for r in rs.runs)]
    if dry_run:
        print("\n".join(commands))
        return None
    meta_path = ROOT / RESULTS / f"{rs.name}.meta.json"
    files = [meta_path, *(ROOT / RESULTS / r.report for r in rs.runs)]
    before = {p: p.read_bytes() if p.exists() else None for p in files}
    shutil.rmtree(ROOT / _B / rs.name, ignore_errors=True)
    (ROOT / RESULTS).mkdir(parents=True, exist_ok=True)
    meta = {"set": rs.name, **provenance(threads)}
    env = os.environ | meta["env"]
    log = ROOT / _B / f"{rs.name}.log"
    log.parent.mkdir(parents=True, exist_ok=True)
    steps, t_set = [], time.perf_counter()
    try:
        with log.open("w") as out:
            for command in commands:
                print(f"record {rs.name}: {command}", flush=True)
                t0 = time.perf_counter()
                subprocess.run(argv(command), cwd=ROOT, env=env, check=True, stdout=out, stderr=subprocess.STDOUT)
                steps.append({"command": command, "wall_s": round(time.perf_counter() - t0, 1)})
    except (subprocess.CalledProcessError, KeyboardInterrupt) as e:
        for p, content in before.items():
            if content is None:
                p.unlink(missing_ok=True)
            else:
                p.write_bytes(content)
        raise SystemExit(f"record {rs.name}: {e}; its files under {RESULTS} are as they were (log: {log})") from e
    meta["machine"]["load_average_end"] = _load()
    meta["wall_s"] = round(time.perf_counter() - t_set, 1)
    meta["commands"] = commands
    meta["runs"] = [{"report": r.report, "command": r.command, "label": r.label} for r in rs.runs]
    meta["steps"] = steps
    if rs.peer:
        meta["peer"] = rs.peer
    meta_path.write_text(json.dumps(meta, indent=1) + "\n")
    print(f"record {rs.name}: {meta['wall_s'] / 60:.1f} min; {', '.join(str(RESULTS / r.report) for r in rs.runs)}")
    return meta


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("set", nargs="?", choices=list(BY_NAME), help="the evaluation set to measure")
    ap.add_argument("--threads", type=int, default=1, help="threads for torch, numba and OpenCV (default 1)")
    ap.add_argument("--dry-run", action="store_true", help="print the commands, run nothing")
    ap.add_argument("--all", action="store_true", help="every set but latency, one after the other")
    ap.add_argument("--list", action="store_true", help="list the sets")
    args = ap.parse_args()
    if args.all:
        for rs in SETS:
            if rs.kind not in ("latency", "live"):  # timings: an idle machine, on their own
                record(rs, args.threads, args.dry_run)
        return
    if args.list or args.set is None:
        print("\n".join(f"{s.name:13} {s.title}" for s in SETS))
        return
    record(BY_NAME[args.set], args.threads, args.dry_run)


if __name__ == "__main__":
    main()
