"""docs/cli/*.md: each command's ``--help`` block is what cog writes for this code (``make docs``).

The blocks are generated (docs/cli/cog_help.py); ``test_cli_pages_are_current`` runs cog in check
mode, in-process, and fails with the diff when a help text changed and the pages were not regenerated.
``test_every_command_has_a_block`` fails when a command has no section of its own.
"""

import io
import re
from pathlib import Path

import pytest
import typer
from cogapp import Cog

from projreg.cli import app as projreg_app
from projsynth.cli import app as projsynth_app

ROOT = Path(__file__).resolve().parents[1]
PAGES = {"projsynth": ROOT / "docs/cli/projsynth.md", "projreg": ROOT / "docs/cli/projreg.md"}
APPS = {"projsynth": projsynth_app, "projreg": projreg_app}


def test_cli_pages_are_current(monkeypatch):
    monkeypatch.setenv("COLUMNS", "200")  # the blocks must not depend on the terminal that runs cog
    out = io.StringIO()
    cog = Cog()
    cog.set_output(stdout=out, stderr=out)
    status = cog.main(["cog", "--check", "--diff", *map(str, PAGES.values())])
    assert status == 0, f"docs/cli/*.md do not match the commands' --help: run `make docs`\n{out.getvalue()}"


@pytest.mark.parametrize("tool", list(PAGES))
def test_every_command_has_a_block(tool):
    blocks = re.findall(r"\[\[\[cog .*help_block\(\"([^\"]+)\"\)", PAGES[tool].read_text())
    commands = typer.main.get_command(APPS[tool]).commands
    assert blocks == [tool, *(f"{tool} {name}" for name in commands)], "one block per command, in --help's order"
