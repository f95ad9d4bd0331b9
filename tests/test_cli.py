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


@pytest.mark.parametrize("has_cuda", [False, True])
def test_device_selection_follows_what_torch_sees(monkeypatch, has_cuda):
    import torch

    monkeypatch.setattr(torch.cuda, "is_available", lambda: has_cuda)
    assert select_device("auto").type == ("cuda" if has_cuda else "cpu")
    assert select_device("cpu").type == "cpu"
    if has_cuda:
        assert select_device("cuda:1") == torch.device("cuda", 1)
    else:
        with pytest.raises(SignSplatError, match="no CUDA device.*allowed here: 'auto' or 'cpu'"):
            select_device("cuda")
    with pytest.raises(SignSplatError, match="unknown device 'tpu'; allowed"):
        select_device("tpu")
