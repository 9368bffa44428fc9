"""The ``--help`` blocks of docs/cli/*.md, written by cog (``make docs``; tests/test_docs.py checks them).

A page holds, between cog's markers in an HTML comment, ``cog.out(help_block("projreg bench"))``; cog
replaces what follows, up to ``[[[end]]]``, with that command's ``--help`` in a ``text`` fence. cog puts
the page's folder on ``sys.path``, hence this module's place beside the pages.

The text is what an 80-column terminal shows, whatever terminal runs cog: the apps run in-process
through Typer's test runner, with click's width set to 78 (in an 80-column terminal click keeps a
2-column margin; the runner's own default, 80, would wrap differently from a real terminal).
"""

import importlib

from typer.testing import CliRunner

MODULES = {"projsynth": "projsynth.cli", "projreg": "projreg.cli"}
TERMINAL_WIDTH = 78  # click's help width in an 80-column terminal (COLUMNS=80)


def help_text(command: str) -> str:
    """The ``--help`` of ``command`` (``"projsynth"``, ``"projsynth gen"``, ...), as printed."""
    tool, *names = command.split()
    app = importlib.import_module(MODULES[tool]).app
    result = CliRunner().invoke(app, [*names, "--help"], prog_name=tool, terminal_width=TERMINAL_WIDTH)
    if result.exit_code != 0:
        raise RuntimeError(f"`{command} --help` exited with {result.exit_code}: {result.output}")
    return result.stdout


def help_block(command: str) -> str:
    """``help_text(command)`` in a Markdown ``text`` fence."""
    return f"```text\n{help_text(command)}```\n"
