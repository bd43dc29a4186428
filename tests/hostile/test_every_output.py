"""The output rule holds for every command and every output flag, found from the parser (not listed by
hand, so a new command is covered the day it is added): an output path that is a FIFO, a socket (stand-ins
for a device: CI never touches /dev) or a symbolic link is refused in one line before any work and left as
it was; a file output that is the command's own input is refused and the input kept."""
from __future__ import annotations

import argparse
import os
import socket

import pytest

from straylight.cli.main import build_parser, main

OUTPUT_DESTS = ("json", "png", "plot", "csv", "html", "output", "out", "report")


def _leaves(parser, prefix=()):
    subs = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    for action in subs:
        for name, sub in action.choices.items():
            yield from _leaves(sub, (*prefix, name))
    if prefix and not subs:
        yield prefix, parser


def _cases():
    for cmd, parser in _leaves(build_parser()):
        for action in parser._actions:
            if action.dest in OUTPUT_DESTS and action.option_strings and action.nargs != 0:  # not a switch (pst --plot)
                yield pytest.param(cmd, action.dest, id=f"{'-'.join(cmd)}--{action.dest}")


CASES = list(_cases())


def _argv(cmd, out_dest, out_path, tmp_path, input_file):
    """The command with its required arguments filled (positionals: ``input_file``) and ``out_dest``
    pointing at ``out_path``."""
    parser = dict(_leaves(build_parser()))[cmd]
    argv = list(cmd)
    chosen = {g._group_actions[0].dest for g in parser._mutually_exclusive_groups if g.required}
    for action in parser._actions:
        if action.dest in ("help", "force"):
            continue
        if action.dest == out_dest:
            argv += [action.option_strings[-1], str(out_path)]
        elif not action.option_strings:  # a positional: the command's input file
            argv += [str(input_file)]
        elif action.required or action.dest in chosen:
            if action.choices:
                value = str(next(iter(action.choices)))
            elif action.type is not None:  # numbers (ray counts, angles, wavelengths)
                value = "1"
            else:
                value = str(tmp_path / f"fresh_{action.dest}.out")
            argv += [action.option_strings[-1]] + [value] * (action.nargs if isinstance(action.nargs, int) else 1)
    return argv


@pytest.fixture()
def input_file(tmp_path):
    f = tmp_path / "input.toml"
    f.write_text("# an input file: its bytes must survive\n")
    return f


def _one_line(capsys, *words):
    err = [e for e in capsys.readouterr().err.strip().splitlines() if e.strip()]
    assert len(err) == 1, err
    for w in words:
        assert w in err[0], err[0]


def test_every_output_flag_is_found():
    """The walk finds the outputs of the tracing, material, rig and lens commands (a guard on the test)."""
    names = {f"{' '.join(c.values[0])} --{c.values[1]}" for c in CASES}
    for expected in ("trace --json", "pst --out", "material fit --output", "rig scan --output", "view --html",
                     "optics import --out", "ghosts --out", "design baffles --out"):
        assert expected in names, sorted(names)


@pytest.mark.parametrize("cmd, dest", CASES)
def test_a_fifo_socket_or_symlink_output_is_refused_and_kept(cmd, dest, tmp_path, input_file, capsys):
    fifo = tmp_path / "special.out"
    os.mkfifo(fifo)
    capsys.readouterr()
    assert main(_argv(cmd, dest, fifo, tmp_path, input_file)) == 2
    _one_line(capsys, "FIFO", str(fifo))
    assert fifo.is_fifo()

    sock_path = tmp_path / "s.out"
    with socket.socket(socket.AF_UNIX, socket.SOCK_STREAM) as sock:
        sock.bind(str(sock_path))
        assert main(_argv(cmd, dest, sock_path, tmp_path, input_file)) == 2
        _one_line(capsys, "socket")
        assert sock_path.is_socket()

    target = tmp_path / "precious"
    target.mkdir() if dest in ("out", "report") else target.write_text("mine")
    link = tmp_path / "link.out"
    link.symlink_to(target)
    assert main(_argv(cmd, dest, link, tmp_path, input_file)) == 2
    _one_line(capsys, "symbolic link")
    assert link.is_symlink() and (target.is_dir() or target.read_text() == "mine")


@pytest.mark.parametrize("cmd, dest", [c for c in CASES if c.values[1] not in ("out", "report")])
def test_a_file_output_that_is_the_commands_own_input_is_refused(cmd, dest, tmp_path, input_file, capsys):
    parser = dict(_leaves(build_parser()))[cmd]
    if not any(not a.option_strings for a in parser._actions):
        pytest.skip(f"{' '.join(cmd)} takes no input file")
    before = input_file.read_bytes()
    capsys.readouterr()
    assert main(_argv(cmd, dest, input_file, tmp_path, input_file)) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and ("own inputs" in err or "not a folder" in err or "is a file" in err), err
    assert input_file.read_bytes() == before


def test_a_device_output_is_refused(tmp_path, monkeypatch, capsys):
    """A character or block device (``--json /dev/null`` as root replaced the real device): refused in one line.
    CI never touches /dev: the path's lstat reports a character device."""
    import stat as stat_mod

    fake = tmp_path / "device.json"
    fake.write_text("")
    real_lstat = os.lstat

    class DeviceStat:
        def __init__(self, st):
            self._st = st
            self.st_mode = stat_mod.S_IFCHR | 0o666

        def __getattr__(self, name):
            return getattr(self._st, name)

    monkeypatch.setattr(os, "lstat", lambda p, *a, **k: DeviceStat(real_lstat(p, *a, **k))
                        if os.fspath(p) == os.fspath(fake) else real_lstat(p, *a, **k))
    capsys.readouterr()
    assert main(["material", "show", "z302_sample_b", "--json", str(fake)]) == 2
    _one_line(capsys, "a device", str(fake))
