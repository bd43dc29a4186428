"""What a new user meets first on the command line: --version, requests refused before any work,
ray counts written as 1e5, --debug after the command, a suggestion for a mistyped flag, help texts without
reST markup, distinct descriptions, the licence in SPDX form."""
import argparse
import re
import time
import tomllib
from pathlib import Path

import pytest

from straylight.cli.main import build_parser, main

ROOT = Path(__file__).resolve().parents[2]


def test_version(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["--version"])
    assert exc.value.code == 0 and capsys.readouterr().out.startswith("straylight ")


@pytest.mark.parametrize("argv, message", [
    (["--angles-deg", "95"], "--angles-deg must be in (-90, 90) deg"),
    (["--rays", "0"], "--rays must be >= 1, got 0"),
    (["--rays", "-5"], "--rays must be >= 1, got -5"),
])
def test_bad_requests_are_refused_before_the_scene_is_read(tmp_path, capsys, argv, message):
    start = time.perf_counter()
    code = main(["pst", str(tmp_path / "missing.toml"), "--out", str(tmp_path / "out"), *argv])
    err = capsys.readouterr().err
    assert code == 2 and message in err and "missing.toml" not in err  # refused before the scene is opened
    assert time.perf_counter() - start < 5


def test_ray_counts_as_people_write_them(capsys):
    parser = build_parser()
    for text, value in (("1e5", 100_000), ("100_000", 100_000), ("250000", 250_000)):
        assert parser.parse_args(["pst", "--builtin", "tube", "--rays", text, "--out", "x"]).rays == value
    with pytest.raises(SystemExit):
        parser.parse_args(["pst", "--builtin", "tube", "--rays", "1.5", "--out", "x"])
    assert "expected a whole number of rays" in capsys.readouterr().err


def test_debug_after_the_command_shows_the_traceback(tmp_path):
    with pytest.raises(Exception, match="scene file not found"):
        main(["geometry", "check", str(tmp_path / "missing.toml"), "--debug"])
    assert main(["geometry", "check", str(tmp_path / "missing.toml")]) == 2


def test_a_mistyped_flag_gets_a_suggestion(capsys):
    with pytest.raises(SystemExit):
        main(["pst", "--builtin", "tube", "--rayz", "10", "--out", "x"])
    assert "--rayz: did you mean --rays?" in capsys.readouterr().err


def _parsers(parser, path=()):
    yield path, parser
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield from _parsers(sub, (*path, name))


def test_help_texts_have_no_rest_markup_and_thermal_and_exchange_differ():
    parsers = dict(_parsers(build_parser()))
    for path, parser in parsers.items():
        text = parser.format_help()
        assert "`" not in text, (path, [line for line in text.splitlines() if "`" in line])
        assert not re.search(r"[Ii]ssue #?\d", text), path  # what, not which issue
    assert parsers[("thermal",)].description != parsers[("exchange",)].description


def test_licence_is_an_spdx_expression():
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())
    assert project["project"]["license"] == "MIT"
    assert int(project["build-system"]["requires"][0].split(">=")[1]) >= 77  # setuptools reads PEP 639 from 77


def test_view_without_a_display_says_where_the_picture_went(tmp_path, monkeypatch, capsys):
    step = ROOT / "tests" / "data" / "cad" / "fusion_like_scope.step"
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    monkeypatch.chdir(tmp_path)
    assert main(["view", str(step)]) == 0
    assert "no display: wrote the picture to scene.png" in capsys.readouterr().out
    assert (tmp_path / "scene.png").is_file()


def _subcommands(parser) -> dict:
    return next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction)).choices


def _surface(parser) -> list:
    """Every (subcommand path, option strings, dest, default, type, choices, nargs, help) of ``parser``."""
    return [(path, tuple(a.option_strings), a.dest, repr(a.default), getattr(a.type, "__name__", repr(a.type)),
             tuple(a.choices) if isinstance(a.choices, (list, tuple)) else None, a.nargs, a.help)
            for path, p in _parsers(parser) for a in p._actions if not isinstance(a, argparse._SubParsersAction)]


def test_a_command_builds_only_its_own_group_and_the_same_subparser():
    """A run of ``straylight CMD`` builds only CMD's group (main.GROUP_OF_COMMAND): the table names the module
    that registers each own command, and the command's parser is the full parser's, flag for flag."""
    import importlib

    from straylight.cli.main import GROUP_OF_COMMAND, OWN_GROUPS

    registered = {}
    for module in OWN_GROUPS:
        sub = argparse.ArgumentParser().add_subparsers()
        importlib.import_module(module).add_parser(sub)
        registered.update(dict.fromkeys(sub.choices, module))
    assert GROUP_OF_COMMAND == registered
    full = _subcommands(build_parser())
    for command in GROUP_OF_COMMAND:
        own = _subcommands(build_parser(command))
        assert command in own and set(own) <= set(GROUP_OF_COMMAND)
        assert _surface(own[command]) == _surface(full[command]), command
    assert "rig" in full and "rig" not in _subcommands(build_parser("pst"))  # entry points: only when needed
    assert set(_subcommands(build_parser("rig"))) == set(full)  # another package's command: the full parser
