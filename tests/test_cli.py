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


@pytest.mark.parametrize("argv", [
    ["body-model", "--out", "x.npz"],
    ["gloss-library", "--out", "x.parquet"],
    ["train-avatar", "--body", "b.npz", "--frames", "f.parquet", "--cameras", "c.parquet",
     "--smplx", "s.parquet", "--out", "out"],
])
def test_a_config_json_that_is_not_json_is_named_in_a_message(argv, capsys, tmp_path,
                                                               monkeypatch):
    """Every command's --config-json goes through signsplat.config.json_option: bad JSON is a
    one-line error naming the option, before any file is read or written."""
    monkeypatch.chdir(tmp_path)
    assert main([*argv, "--config-json", "{not json"]) == 2
    err = capsys.readouterr().err
    assert f"signsplat {argv[0]}: error: --config-json: not valid JSON" in err, err
    assert not any(tmp_path.iterdir())
