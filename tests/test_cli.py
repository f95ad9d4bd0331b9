"""The command line lists its commands and turns user errors into a message, not a traceback."""

import subprocess
import sys

from signsplat.cli import COMMANDS, main
from signsplat.device import select_device
from signsplat.errors import SignSplatError

import pytest


def test_help_lists_every_command(capsys):
    assert main(["--help"]) == 0
    out = capsys.readouterr().out
    assert all(name in out for name in COMMANDS)


def test_unknown_command(capsys):
    assert main(["fly"]) == 2
    assert "unknown command 'fly'" in capsys.readouterr().err


def test_module_entry_point_runs():
    res = subprocess.run([sys.executable, "-m", "signsplat", "--help"], capture_output=True,
                         text=True, check=True)
    assert "usage: signsplat" in res.stdout


def test_device_selection():
    assert select_device("cpu").type == "cpu"
    assert select_device("auto").type in ("cpu", "cuda")
    with pytest.raises(SignSplatError, match="allowed"):
        select_device("tpu")
