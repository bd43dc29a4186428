import pytest

from contract_helpers import run_cli


@pytest.fixture
def cli(capsys):
    """``cli(*argv)`` -> (exit code, stdout, stderr) of an in-process ``straylight`` call."""
    return lambda *argv: run_cli(argv, capsys)
