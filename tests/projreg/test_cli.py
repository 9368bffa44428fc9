"""The ``projreg`` command line: every command has help that states what it does."""

import typer
from typer.testing import CliRunner

from projreg.cli import app

COMMANDS = {"train", "export", "bench", "predict", "compensate", "warp", "live"}


def test_every_command_has_help():
    runner = CliRunner()
    group = typer.main.get_command(app)
    assert set(group.commands) == COMMANDS
    result = runner.invoke(app, ["--help"])
    assert result.exit_code == 0 and all(name in result.stdout for name in COMMANDS)
    for name, command in group.commands.items():
        result = runner.invoke(app, [name, "--help"])
        assert result.exit_code == 0, (name, result.output)
        summary = command.help.splitlines()[0].split(";")[0]
        assert summary and summary in " ".join(result.stdout.split()), name
        for param in command.params:  # every option explains itself
            assert param.help or param.name == "help", (name, param.name)
