"""Shell recipes (examples/, bench/device_run.sh) call only commands and options that exist."""

import re
import subprocess
from pathlib import Path

import pytest
import typer

import projreg.cli
import projsynth.cli

ROOT = Path(__file__).resolve().parents[1]
SCRIPTS = sorted(ROOT.glob("examples/*.sh")) + [ROOT / "bench" / "device_run.sh"]
TOOLS = {"projsynth": projsynth.cli.app, "projreg": projreg.cli.app}
CALL = re.compile(r"\b(projsynth|projreg)(?:\.cli)?\s+([a-z][a-z-]*)((?:[^|;&\n])*)")


def options_of(tool: str) -> dict[str, set[str]]:
    group = typer.main.get_command(TOOLS[tool])
    return {
        name: {opt for p in cmd.params for opt in p.opts + p.secondary_opts} for name, cmd in group.commands.items()
    }


def calls(script: Path) -> list[tuple[str, str, list[str]]]:
    text = script.read_text().replace("\\\n", " ")
    text = "\n".join(line for line in text.splitlines() if not line.lstrip().startswith("#"))
    return [(tool, cmd, re.findall(r"(?<![\w-])--[a-z][a-z-]*", rest)) for tool, cmd, rest in CALL.findall(text)]


@pytest.mark.parametrize("script", SCRIPTS, ids=lambda p: p.name)
def test_script_is_valid_bash_and_calls_existing_options(script):
    subprocess.run(["bash", "-n", str(script)], check=True)
    found = calls(script)
    assert found, f"{script.name}: no projsynth/projreg call found"
    for tool, cmd, opts in found:
        known = options_of(tool)
        assert cmd in known, f"{script.name}: `{tool} {cmd}` is not a command"
        unknown = [o for o in opts if o not in known[cmd]]
        assert not unknown, f"{script.name}: `{tool} {cmd}` has no option {', '.join(unknown)}"


def test_the_checker_catches_a_misspelt_option(tmp_path):
    bad = tmp_path / "bad.sh"
    bad.write_text("projreg train --data d \\\n  --stpes 3\n")
    ((tool, cmd, opts),) = calls(bad)
    assert (tool, cmd) == ("projreg", "train") and "--stpes" in opts and "--stpes" not in options_of(tool)[cmd]
