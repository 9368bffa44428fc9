"""Help that reads at 80 columns, for every command of both tools (issue 18).

Each command's ``--help`` is rendered with ``COLUMNS=80``: no line is wider, every option name and
every shown default is there in full, and values are named as the docs name them (``DIR``, ``N``),
never as Typer's ``<list[Path]>``, ``<bool>`` or ``{root}``.
"""

import re

import pytest
import typer
from typer.testing import CliRunner

from projreg.cli import app as projreg_app
from projsynth.cli import app as projsynth_app

APPS = {"projsynth": projsynth_app, "projreg": projreg_app}
COMMANDS = [(tool, name) for tool, app in APPS.items() for name in typer.main.get_command(app).commands]


def _help(tool: str, name: str) -> str:
    result = CliRunner().invoke(APPS[tool], [name, "--help"], env={"COLUMNS": "80"}, prog_name=tool)
    assert result.exit_code == 0, (tool, name, result.output)
    return result.stdout


@pytest.mark.parametrize(("tool", "name"), COMMANDS, ids=[f"{t} {n}" for t, n in COMMANDS])
def test_help_reads_at_80_columns(tool, name):
    text = _help(tool, name)
    assert max(len(line) for line in text.splitlines()) <= 80, text
    assert not re.search(r"<(bool|int|float|str|path|Path|list\[[^]]*\])>|\{\w+\}", text), text
    flat = " ".join(text.split())
    command = typer.main.get_command(APPS[tool]).commands[name]
    for param in command.params:
        for opt in [*param.opts, *param.secondary_opts] if param.param_type_name == "option" else []:
            assert re.search(rf"(^|[\s,/]){re.escape(opt)}([\s,]|$)", text, re.M), (opt, text)
        if param.param_type_name == "argument":
            assert param.metavar and param.metavar in text.splitlines()[0], (param.name, text)
        if param.param_type_name == "option" and param.show_default and param.default not in (None, False, ()):
            shown = re.search(r"\[default: ([^]]*)\]", flat[flat.index(param.opts[0]) :])
            assert shown and " " not in shown.group(1).strip(), (param.name, text)  # not split by wrapping
