"""The house stays standing: no import cycle between modules, no module over 600 lines, and the layering
of pyproject.toml's import-linter contracts (which `make lint` checks) really refuses an import upwards."""

import subprocess
import sys
from pathlib import Path

import grimp
import pytest

ROOT = Path(__file__).resolve().parents[1]
MAX_LINES = 600


def _cycles(graph: grimp.ImportGraph) -> list[list[str]]:
    """Strongly connected groups of more than one module (Tarjan), each an import cycle."""
    index, low, stack, on, out, counter = {}, {}, [], set(), [], [0]

    def visit(v: str) -> None:
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in graph.find_modules_directly_imported_by(v):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            group = []
            while True:
                w = stack.pop()
                on.discard(w)
                group.append(w)
                if w == v:
                    break
            if len(group) > 1:
                out.append(sorted(group))

    for module in sorted(graph.modules):
        if module not in index:
            visit(module)
    return out


def test_no_import_cycle():
    graph = grimp.build_graph("projsynth", "projreg")
    assert _cycles(graph) == []


@pytest.mark.parametrize("package", ["projsynth", "projreg"])
def test_no_module_over_600_lines(package):
    long = {
        str(p.relative_to(ROOT)): n
        for p in (ROOT / package).rglob("*.py")
        if (n := len(p.read_text().splitlines())) > MAX_LINES
    }
    assert long == {}


def test_an_import_upwards_breaks_the_layering(tmp_path):
    """A copy of the packages in which geometry imports the refinement: lint-imports must fail there."""
    for package in ("projsynth", "projreg"):
        subprocess.run(["cp", "-r", str(ROOT / package), str(tmp_path / package)], check=True)
    (tmp_path / "pyproject.toml").write_text((ROOT / "pyproject.toml").read_text())
    lint = [str(Path(sys.executable).with_name("lint-imports"))]
    assert subprocess.run(lint, cwd=tmp_path, capture_output=True, text=True).returncode == 0
    bad = tmp_path / "projreg" / "geometry" / "warp.py"
    bad.write_text(bad.read_text() + "\nfrom ..refine import config  # noqa: E402\n")
    run = subprocess.run(lint, cwd=tmp_path, capture_output=True, text=True)
    assert run.returncode != 0 and "projreg.geometry.warp -> projreg.refine.config" in run.stdout
