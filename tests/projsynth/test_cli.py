"""The ``projsynth`` command line: help everywhere, one-line errors naming the option or file, tables."""

import json
import re
import shutil
import subprocess
import sys
import typing
from pathlib import Path

import pytest
import typer
from typer.testing import CliRunner

from projsynth.cli import app

COMMANDS = {
    "gen",
    "merge",
    "verify",
    "inspect",
    "export",
    "preview",
    "transforms",
    "patterns",
    "capture",
    "decode",
    "response",
}
SMALL = ["--pairs", "1", "--size", "48x64", "--transforms", "0-3", "--shard-size", "2"]  # 8 samples, 4 shards


def test_every_command_has_help(cli):
    group = typer.main.get_command(app)
    assert set(group.commands) == COMMANDS
    result = cli.run("--help")
    assert result.exit_code == 0 and all(name in result.stdout for name in COMMANDS)
    for name, command in group.commands.items():
        result = cli.run(name, "--help")
        assert result.exit_code == 0, (name, result.stderr)
        summary = command.help.splitlines()[0].split(";")[0]
        assert summary and summary in " ".join(result.stdout.split()), name


# --- gen: bad options -------------------------------------------------------------------------------

BAD_GEN = [
    (["--size", "10x10"], "--size"),
    (["--size", "abc"], "--size"),
    (["--size", "64x96x3"], "--size"),
    (["--transforms", "0-999"], "--transforms"),
    (["--transforms", "a-b"], "--transforms"),
    (["--transforms", "3-1"], "--transforms"),
    (["--transforms", " "], "--transforms"),
    (["--split", "foo"], "--split"),
    (["--blend", "foo"], "--blend"),
    (["--pairs", "0"], "--pairs"),
    (["--seed", "-1"], "--seed"),
    (["--shard-size", "0"], "--shard-size"),
    (["--workers", "0"], "--workers"),
    (["--shards", "5-2"], "--shards"),
    (["--shards", "x"], "--shards"),
    (["--shards", "-1"], "--shards"),
    (["--shards", "0-4"], "--shards"),  # the plan has shards 0-3
    (["--shards", "4"], "--shards"),
]


@pytest.mark.parametrize(("extra", "option"), BAD_GEN, ids=[" ".join(e) for e, _ in BAD_GEN])
def test_gen_rejects_bad_options(cli, tmp_path, extra, option):
    out = tmp_path / "ds"
    line = cli.assert_one_line_error(cli.run("gen", "--out", out, *SMALL, *extra), option)
    assert line.startswith(f"{cli.ERROR_PREFIX}{option}")
    assert not out.exists()  # nothing is created before the options are checked


def test_gen_natural_without_generated(cli, tmp_path):
    (tmp_path / "nat").mkdir()
    out = tmp_path / "ds"
    cli.assert_one_line_error(
        cli.run("gen", "--out", out, *SMALL, "--natural", tmp_path / "nat"), "--natural", "--generated"
    )
    assert not out.exists()


def test_gen_empty_image_folder(cli, tmp_path):
    for name in ("nat", "gen"):
        (tmp_path / name).mkdir()
    result = cli.run(
        "gen", "--out", tmp_path / "ds", *SMALL, "--natural", tmp_path / "nat", "--generated", tmp_path / "gen"
    )
    cli.assert_one_line_error(result, "--natural", tmp_path / "nat")


def test_gen_out_under_a_regular_file(cli, tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("not a directory")
    cli.assert_one_line_error(cli.run("gen", "--out", blocker / "ds", *SMALL), "--out", blocker / "ds")
    assert blocker.read_text() == "not a directory"


def test_gen_refuses_an_out_made_with_other_options(cli, planar_ds, copy_dataset):
    root = copy_dataset(planar_ds)
    before = cli.shard_mtimes(root)
    seed12 = [a if a != "11" else "12" for a in cli.PLANAR]
    for options in ([*seed12, "--shard-size", "8"], [*cli.PLANAR, "--shard-size", "13"]):
        cli.assert_one_line_error(cli.run("gen", "--out", root, *options), "--out", root / "dataset.json")
    assert cli.shard_mtimes(root) == before
    assert cli.run("verify", root, "-q").exit_code == 0


def test_gen_refuses_shards_without_a_plan(cli, planar_ds, copy_dataset):
    root = copy_dataset(planar_ds)
    (root / "dataset.json").unlink()
    cli.assert_one_line_error(cli.run("gen", "--out", root, *cli.PLANAR, "--shard-size", "8"), "--out")


def test_gen_refuses_a_folder_of_other_files_and_resumes_its_own(cli, tmp_path):
    tiny = ["--pairs", "1", "--size", "48x64", "--transforms", "0", "--shard-size", "1", "-q"]
    photos = tmp_path / "photos"
    photos.mkdir()
    for name in ("IMG_0001.jpg", "notes.txt"):
        (photos / name).write_bytes(b"someone's file")
    line = cli.assert_one_line_error(cli.run("gen", "--out", photos, *tiny), f"--out {photos}: holds 2 file(s)")
    assert "(e.g. IMG_0001.jpg)" in line and "choose a new or empty folder" in line
    assert sorted(p.name for p in photos.iterdir()) == ["IMG_0001.jpg", "notes.txt"]
    assert (photos / "notes.txt").read_bytes() == b"someone's file"
    hidden = tmp_path / "hidden"  # names beginning with a dot, which file managers hide, are not counted
    hidden.mkdir()
    (hidden / ".DS_Store").write_bytes(b"finder")
    assert cli.run("gen", "--out", hidden, *tiny).exit_code == 0
    (hidden / "shard-00001.h5").unlink()  # an interrupted run: one shard and the manifest missing
    (hidden / "manifest.json").unlink()
    (hidden / "shard-00001.h5.tmp").write_bytes(b"\x89HDF partial")
    result = cli.run("gen", "--out", hidden, *tiny[:-1])
    assert result.exit_code == 0, result.stderr
    assert cli.summary(result) == (1, 1, 2)
    assert (hidden / ".DS_Store").read_bytes() == b"finder"


def test_type_errors_exit_2(cli, tmp_path):
    # Parsed by typer itself (a multi-line usage message, not ours): only the exit status is checked.
    result = cli.run("gen", "--out", tmp_path / "ds", "--pairs", "many")
    assert result.exit_code == 2 and "--pairs" in result.stderr
    assert cli.run("gen").exit_code == 2  # --out is required


# --- other commands: bad options --------------------------------------------------------------------


def test_preview_count_zero(cli, mixed_ds, tmp_path):
    cli.assert_one_line_error(cli.run("preview", mixed_ds, "--out", tmp_path / "p.png", "--count", "0"), "--count")
    assert not (tmp_path / "p.png").exists()


def test_export_out_under_a_regular_file(cli, mixed_ds, tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("x")
    cli.assert_one_line_error(cli.run("export", mixed_ds, "--out", blocker / "e", "--limit", "1"), "--out")


def test_export_negative_limit(cli, mixed_ds, tmp_path):
    cli.assert_one_line_error(cli.run("export", mixed_ds, "--out", tmp_path / "e", "--limit", "-1"), "--limit")


# --- transform tables -------------------------------------------------------------------------------


def test_transforms_listing(cli):
    result = cli.run("transforms")
    assert result.exit_code == 0
    lines = result.stdout.splitlines()
    assert lines[0] == "table builtin-v1: 160 configurations" and len(lines) == 161
    assert [int(line.split()[0]) for line in lines[1:]] == list(range(160))
    cli.assert_one_line_error(cli.run("transforms", "--json", "--toml"), "--json", "--toml")


def test_toml_round_trip_reproduces_the_builtin_table(cli, builtin_toml, planar_ds, copy_dataset):
    builtin = json.loads(cli.run("transforms", "--json").stdout)
    result = cli.run("transforms", "--json", "--table", builtin_toml)
    assert result.exit_code == 0, result.stderr
    reloaded = json.loads(result.stdout)
    assert len(builtin["transforms"]) == 160
    assert reloaded == builtin  # version included: the TOML carries it

    # Same table, same config hash: a dataset made with the built-in table resumes with --table.
    root = copy_dataset(planar_ds)
    result = cli.run("gen", "--out", root, *cli.PLANAR, "--shard-size", "8", "--table", builtin_toml)
    assert result.exit_code == 0, result.stderr
    assert cli.summary(result) == (0, 5, 5)
    assert json.loads((root / "dataset.json").read_text())["table_digest"] == cli.manifest(planar_ds)["table_digest"]


def test_an_edited_table_changes_the_config_hash(cli, builtin_toml, planar_ds, copy_dataset, tmp_path):
    edited = tmp_path / "edited.toml"
    text = builtin_toml.read_text()
    i = text.index("id = 150\n")  # a row the PLANAR datasets do not even use
    edited.write_text(text[:i] + text[i:].replace("bump_sigma = [0.12,", "bump_sigma = [0.13,", 1))
    assert edited.read_text() != text
    cli.assert_one_line_error(
        cli.run("gen", "--out", copy_dataset(planar_ds), *cli.PLANAR, "--shard-size", "8", "--table", edited),
        "--out",
        "made with other options",
    )


def _first_row_edit(text: str, old: str, new: str) -> str:
    assert old in text
    return text.replace(old, new, 1)


BAD_TABLES = {
    "unparseable": lambda t: "[[transform]\nid = 0\n",
    "no rows": lambda t: 'version = "x"\n',
    "missing keys": lambda t: '[[transform]]\nid = 0\nfamily = "planar"\n',
    "missing range": lambda t: re.sub(r"\ntilt_deg = \[[^\]]*\]", "", t, count=1),
    "low > high": lambda t: _first_row_edit(t, "baseline_deg = [1.0, 4.0]", "baseline_deg = [4.0, 1.0]"),
    "out of bounds": lambda t: _first_row_edit(t, "baseline_deg = [1.0, 4.0]", "baseline_deg = [1.0, 400.0]"),
    "not a pair": lambda t: _first_row_edit(t, "baseline_deg = [1.0, 4.0]", "baseline_deg = 2.0"),
    "unknown family": lambda t: _first_row_edit(t, 'family = "planar"', 'family = "torus"'),
    "unknown parameter": lambda t: _first_row_edit(t, "baseline_deg =", "baseline_rad ="),
    "duplicate id": lambda t: _first_row_edit(t, "id = 1\n", "id = 0\n"),
    "not utf-8": lambda t: "\udcff",
}
NEEDLES = {
    "low > high": "baseline_deg",
    "out of bounds": "baseline_deg",
    "unknown family": "torus",
    "unknown parameter": "baseline_rad",
    "missing range": "tilt_deg",
    "missing keys": "geometry",
}


@pytest.mark.parametrize("command", ["gen", "transforms"])
@pytest.mark.parametrize("kind", list(BAD_TABLES))
def test_bad_table_is_one_line_naming_the_file(cli, builtin_toml, tmp_path, kind, command):
    path = tmp_path / "table.toml"
    path.write_bytes(BAD_TABLES[kind](builtin_toml.read_text()).encode("utf-8", "surrogateescape"))
    out = tmp_path / "ds"
    args = ["gen", "--out", out, *SMALL] if command == "gen" else ["transforms", "--json"]
    cli.assert_one_line_error(cli.run(*args, "--table", path), path, NEEDLES.get(kind, ""))
    assert not out.exists()


def test_missing_table_file(cli, tmp_path):
    path = tmp_path / "nope.toml"
    cli.assert_one_line_error(cli.run("transforms", "--table", path), path)


def test_a_small_user_table(cli, builtin_toml, tmp_path):
    text = builtin_toml.read_text()
    rows = text.split("[[transform]]\n")
    small = tmp_path / "two.toml"  # rows 37 and 157 of the built-in table, renumbered 0 and 1
    small.write_text(
        'version = "two"\n\n'
        + "".join("[[transform]]\n" + re.sub(r"^id = \d+", f"id = {i}", r) for i, r in enumerate((rows[38], rows[158])))
    )
    listing = json.loads(cli.run("transforms", "--json", "--table", small).stdout)
    assert listing["version"] == "two" and [t["name"] for t in listing["transforms"]] == [
        "lens-s4-daylight",
        "bumps-s4-daylight",
    ]
    cli.assert_one_line_error(cli.run("gen", "--out", tmp_path / "x", *SMALL, "--table", small), "--transforms")
    out = tmp_path / "ds"
    result = cli.run("gen", "--out", out, "--pairs", "1", "--size", "48x64", "--table", small, "-q")
    assert result.exit_code == 0, result.stderr
    manifest = cli.manifest(out)
    assert manifest["table_version"] == "two" and manifest["transforms"] == [0, 1]
    assert [s["id"] for s in manifest["samples"]] == [f"train-p00000-r{r}-t00{t}" for r in (0, 1) for t in (0, 1)]
    assert cli.run("verify", out, "-q").exit_code == 0


def test_a_dataset_from_another_generator_version_is_named_not_resumed(cli, planar_ds, copy_dataset):
    root = copy_dataset(planar_ds)
    plan = json.loads((root / "dataset.json").read_text())
    (root / "dataset.json").write_text(json.dumps({**plan, "generator": "projsynth 0.1.0"}))
    cli.assert_one_line_error(
        cli.run("gen", "--out", root, *cli.PLANAR, "--shard-size", "8"),
        "--out",
        "made by projsynth 0.1.0",
        "delete it to regenerate",
    )


# --- empty paths ------------------------------------------------------------------------------------


def _is_path(annotation: object) -> bool:
    return annotation is Path or any(_is_path(a) for a in typing.get_args(annotation))


def path_params(application: typer.Typer) -> list[tuple[str, str]]:
    """``(command, option)`` of every option or argument typed as a path (an argument as its metavar)."""
    found = []
    for name, command in typer.main.get_command(application).commands.items():
        hints = typing.get_type_hints(command.callback, include_extras=True)
        for param in command.params:
            if _is_path(hints.get(param.name)):
                found.append((name, param.opts[0] if param.param_type_name == "option" else param.metavar))
    return found


PATH_PARAMS = path_params(app)


@pytest.mark.parametrize(("command", "option"), PATH_PARAMS, ids=[" ".join(p) for p in PATH_PARAMS])
def test_an_empty_path_is_refused_naming_its_option(cli, tmp_path, monkeypatch, command, option):
    """``''`` (an unset shell variable) is refused, not read as the current folder and blamed on its files."""
    assert len(PATH_PARAMS) >= 20  # the annotations are read: none missed by a change in typer
    monkeypatch.chdir(tmp_path)
    result = cli.run(command, *([""] if option == "DIR" else [option, ""]))
    assert result.exit_code == 2 and f"Invalid value for '{option}': empty; give" in result.stderr, result.stderr
    assert not list(tmp_path.iterdir())


def test_an_empty_pair_is_refused(cli, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    for pair in (["", "photo.png"], ["picture.png", " "]):
        result = cli.run("decode", "--captures", "photos", "--out", "o", "--patterns", "pat", "--pair", *pair)
        cli.assert_one_line_error(result, "--pair: empty; give the paths of a picture and of its photo")
    assert not list(tmp_path.iterdir())


# --- usage errors through the console entry points --------------------------------------------------

USAGE_ERRORS = [
    ("projsynth", ["gen", "--out", "x", "--pairs", "abc"], "Invalid value for '--pairs'", "projsynth gen --help"),
    ("projsynth", ["gen"], "Missing option '--out'", "projsynth gen --help"),
    ("projsynth", ["nope"], "No such command 'nope'", "projsynth --help"),
    (
        "projreg",
        ["train", "--data", "d", "--out", "o", "--steps", "x"],
        "Invalid value for '--steps'",
        "projreg train --help",
    ),
    ("projreg", ["predict", "--max-side", "abc"], "Invalid value for '--max-side'", "projreg predict --help"),
    ("projsynth", ["verify", ""], "Invalid value for 'DIR': empty; give the path to read", "projsynth verify --help"),
    (
        "projsynth",
        ["decode", "--captures", ""],
        "Invalid value for '--captures': empty; give the path to read",
        "projsynth decode --help",
    ),
]


@pytest.mark.parametrize(
    ("tool", "args", "message", "hint"), USAGE_ERRORS, ids=[" ".join(a) for _, a, _, _ in USAGE_ERRORS]
)
def test_usage_errors_are_one_line_from_the_console_commands(tool, args, message, hint, tmp_path):
    done = subprocess.run(
        [sys.executable, "-m", f"{tool}.cli", *args], capture_output=True, text=True, cwd=tmp_path, timeout=120
    )
    lines = [line for line in done.stderr.splitlines() if line.strip()]
    assert done.returncode == 2 and len(lines) == 1, (done.returncode, done.stderr)
    assert lines[0].startswith(f"{tool}: error: {message}") and lines[0].endswith(f"see `{hint}`"), lines[0]
    assert not list(tmp_path.iterdir())


def test_console_help_exits_0():
    for tool in ("projsynth", "projreg"):
        done = subprocess.run(
            [sys.executable, "-m", f"{tool}.cli", "--help"], capture_output=True, text=True, timeout=120
        )
        assert done.returncode == 0 and "Usage:" in done.stdout, (tool, done.stderr)


def test_an_input_error_is_one_line_with_no_bar_before_it(cli, tmp_path):
    """``projsynth verify /nonexistent``: the error, and no empty bar (``verify: 0sample``) on its line."""
    for args in (
        ["verify", tmp_path / "nonexistent"],
        ["inspect", tmp_path / "nonexistent"],
        ["export", tmp_path / "nonexistent", "--out", tmp_path / "x"],
    ):
        result = cli.run(*args)
        assert result.exit_code == 2
        assert result.stderr.count("\n") == 1 and "\r" not in result.stderr, repr(result.stderr)
        assert result.stderr.startswith(cli.ERROR_PREFIX) and "sample" not in result.stderr.split(":")[2]


# --- response: the devices' curves from the virtual rig's photos of grey levels ------------------------


@pytest.fixture(scope="module")
def grey_shots(tmp_path_factory):
    """A response set of 9 levels for a 48 x 64 projector and the virtual rig's photos of it (studio light)."""
    root = tmp_path_factory.mktemp("response")
    runner = CliRunner()
    args = ["patterns", "--kind", "response", "--size", "48x64", "--levels", "9", "--out", str(root / "pat")]
    assert runner.invoke(app, args).exit_code == 0
    args = ["capture", "--patterns", str(root / "pat"), "--out", str(root / "cap"), "--transform", "0", "--seed", "2"]
    assert runner.invoke(app, args).exit_code == 0
    return root


def test_response_is_fitted_from_the_virtual_rig_s_photos(cli, grey_shots, tmp_path):
    out = tmp_path / "cal" / "response.json"
    result = cli.run("response", "--patterns", grey_shots / "pat", "--captures", grey_shots / "cap", "--out", out)
    assert result.exit_code == 0, result.stderr
    assert "9 levels" in result.stderr and "camera exponent" in result.stderr
    record = json.loads(out.read_text())
    assert record["projector"]["levels"] == [0, 32, 64, 96, 128, 159, 191, 223, 255]
    assert record["fit"]["photos"][0] == "00-level000.png" and record["fit"]["camera_size"] == [48, 64]


def test_response_refusals_are_one_line_and_write_nothing(cli, grey_shots, tmp_path):
    pat, cap = grey_shots / "pat", grey_shots / "cap"
    dark = tmp_path / "dark"
    shutil.copytree(cap, dark)
    for photo in dark.glob("*.png"):  # the projector off: every photo the black one
        shutil.copy(cap / "00-level000.png", photo)
    cases = [
        (["--captures", cap, "--out", tmp_path / "r.txt"], "one JSON file"),
        (["--captures", tmp_path / "none", "--out", tmp_path / "r.json"], "--captures"),
        (["--captures", dark, "--out", tmp_path / "r.json"], "barely differ"),
        (["--captures", cap, "--out", cap / "00-level000.png"], "one JSON file"),
    ]
    for extra, needle in cases:
        cli.assert_one_line_error(cli.run("response", "--patterns", pat, *extra), needle)
    dots = tmp_path / "dots"
    assert cli.run("patterns", "--kind", "dots", "--size", "48x64", "--grid", "4x4", "--out", dots).exit_code == 0
    cli.assert_one_line_error(
        cli.run("response", "--patterns", dots, "--captures", cap, "--out", tmp_path / "r.json"), "a dots set"
    )
    cli.assert_one_line_error(
        cli.run("decode", "--patterns", pat, "--captures", cap, "--out", tmp_path / "d"), "projsynth response"
    )
    assert not (tmp_path / "r.json").exists() and not (tmp_path / "r.txt").exists()


@pytest.mark.parametrize(
    ("extra", "needle"),
    [
        (["--kind", "response", "--levels", "4"], "--levels: must be in 5..256"),
        (["--kind", "graycode", "--levels", "9"], "--levels"),
    ],
)
def test_patterns_levels_are_checked(cli, tmp_path, extra, needle):
    cli.assert_one_line_error(cli.run("patterns", "--size", "48x64", "--out", tmp_path / "p", *extra), needle)
    assert not (tmp_path / "p").exists()


def test_patterns_period_zero_is_refused_not_replaced_by_the_default(cli, tmp_path):
    cli.assert_one_line_error(
        cli.run("patterns", "--kind", "graycode", "--size", "48x64", "--out", tmp_path / "p", "--period", "0"),
        "--period: must be a multiple of 4 in 8..1024, got 0",
    )
    assert not (tmp_path / "p").exists()


def test_patterns_refuse_a_folder_of_other_files_and_rewrite_their_own(cli, tmp_path):
    photos = tmp_path / "photos"
    photos.mkdir()
    (photos / "00-col6.png").write_bytes(b"a photo named after its pattern")
    args = ("patterns", "--kind", "opencv-graycode", "--size", "48x64", "--out")
    cli.assert_one_line_error(cli.run(*args, photos), "holds 1 file(s) of something else (e.g. 00-col6.png)")
    assert (photos / "00-col6.png").read_bytes() == b"a photo named after its pattern"
    assert cli.run(*args, tmp_path / "pat").exit_code == 0
    assert cli.run(*args, tmp_path / "pat").exit_code == 0  # the same set again: rewritten, same bytes
    other = cli.run("patterns", "--kind", "graycode", "--size", "48x64", "--out", tmp_path / "pat")
    cli.assert_one_line_error(other, "of something else")
