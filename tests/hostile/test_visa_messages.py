"""Hostile input: pyvisa-sim put a whole traceback inside its one-line error for a definitions file it
cannot parse; the rig's message is now the file's problem, on one line, without the traceback."""
from __future__ import annotations

from rig.drivers.visa import InstrumentError, one_line, open_resource
from straylight.cli.main import main


def test_bad_sim_definitions_one_line(tmp_path, capsys):
    bad = tmp_path / "broken.yaml"
    bad.write_text("spec: [unclosed\n")
    config = tmp_path / "rig.toml"
    config.write_text(f'[motion]\nresource = "GPIB0::1::INSTR"\nvisa_library = "{bad}@sim"\n'
                      f'[lockin]\nresource = "GPIB0::8::INSTR"\nvisa_library = "{bad}@sim"\n')
    assert main(["rig", "scan", "--hardware", str(config), "--sample", "x", "-o", str(tmp_path / "x.csv")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "Traceback" not in err and "File \"" not in err and "\\n" not in err, err
    assert "cannot open VISA resource 'GPIB0::1::INSTR'" in err and "broken.yaml\", line 1, column 7" in err


def test_missing_sim_file_names_it():
    try:
        open_resource("GPIB0::1::INSTR", visa_library="no_such_definitions.yaml@sim")
    except InstrumentError as exc:
        text = str(exc)
    assert "Traceback" not in text and "No such file or directory: 'no_such_definitions.yaml" in text


def test_one_line_keeps_plain_messages():
    assert one_line(ValueError("a\n  b")) == "a b"
