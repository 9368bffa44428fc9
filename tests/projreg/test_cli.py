"""The ``projreg`` command line: every command has help that states what it does; an empty path is refused."""

import typing
from pathlib import Path

import pytest
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


def _is_path(annotation: object) -> bool:
    return annotation is Path or any(_is_path(a) for a in typing.get_args(annotation))


def _path_options() -> list[tuple[str, str]]:
    """``(command, option)`` of every option typed as a path."""
    found = []
    for name, command in typer.main.get_command(app).commands.items():
        hints = typing.get_type_hints(command.callback, include_extras=True)
        found += [(name, p.opts[0]) for p in command.params if _is_path(hints.get(p.name))]
    return found


PATH_OPTIONS = _path_options()


@pytest.mark.parametrize(("command", "option"), PATH_OPTIONS, ids=[" ".join(p) for p in PATH_OPTIONS])
def test_an_empty_path_is_refused_naming_its_option(tmp_path, monkeypatch, command, option):
    """``''`` (an unset shell variable) is refused, not read as the current folder and blamed on its files."""
    assert {"--white", "--black", "--response", "--model", "--data", "--checkpoint"} <= {o for _, o in PATH_OPTIONS}
    monkeypatch.chdir(tmp_path)
    result = CliRunner().invoke(app, [command, option, ""])
    assert result.exit_code == 2 and f"Invalid value for '{option}': empty; give" in result.stderr, result.stderr
    assert not list(tmp_path.iterdir())


def test_an_empty_init_is_refused_not_ignored(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    result = CliRunner().invoke(app, ["train", "--data", "d", "--out", "run", "--init", ""])
    assert (
        result.exit_code == 2
        and result.stderr == "projreg: error: --init: empty; give a checkpoint file or `reference`\n"
    )
    assert not list(tmp_path.iterdir())
