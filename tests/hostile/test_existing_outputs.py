"""An existing output file is replaced only with --force, unless straylight wrote it and it is unchanged
(docs/reference/commands.md, "Outputs"): a user's file survives a command pointed at it by mistake."""
import json

import pytest

from straylight.cli.main import build_parser, main

EVAL = ["material", "eval", "z302_sample_b", "--theta-i-deg", "10", "--theta-r-deg", "20", "--polarization", "u"]


def test_a_users_file_is_refused_without_force_and_kept(tmp_path, capsys):
    mine = tmp_path / "notes.json"
    mine.write_text('{"mine": true}\n')
    assert main([*EVAL, "--json", str(mine)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(mine) in err[0] and "--force" in err[0]
    assert mine.read_text() == '{"mine": true}\n'
    assert main([*EVAL, "--json", str(mine), "--force"]) == 0
    assert "brdf_per_sr" in json.loads(mine.read_text())


def test_a_rerun_replaces_its_own_unchanged_output_but_not_an_edited_one(tmp_path, capsys):
    out = tmp_path / "out.json"
    assert main([*EVAL, "--json", str(out)]) == 0
    assert main([*EVAL, "--json", str(out)]) == 0  # its own result, unchanged: replaced
    out.write_text(out.read_text().replace("{", '{"edited": 1, ', 1))
    assert main([*EVAL, "--json", str(out)]) == 2
    assert "did not write it (or it changed since)" in capsys.readouterr().err
    assert json.loads(out.read_text())["edited"] == 1


def test_an_empty_file_is_no_one_s_data(tmp_path):
    out = tmp_path / "placeholder.json"
    out.touch()
    assert main([*EVAL, "--json", str(out)]) == 0


def _commands(parser, prefix=()):
    import argparse

    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield from _commands(sub, (*prefix, name))
    if prefix:
        yield prefix, {a.dest for a in parser._actions}


@pytest.mark.parametrize("flag", ["json", "png", "plot", "csv", "html", "output"])
def test_every_command_writing_a_file_takes_force(flag):
    writers = [(c, d) for c, d in _commands(build_parser()) if flag in d]
    assert writers or flag in ("plot", "csv")
    assert all("force" in d for c, d in writers), [c for c, d in writers if "force" not in d]
