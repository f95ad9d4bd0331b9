"""``signsplat body-model``: proxy or a checked copy of a given file; errors exit 2."""

from __future__ import annotations

import json
import shutil

import numpy as np

from signsplat.cli import main


def test_copies_and_checks_a_given_file(proxy_body_path, tmp_path, capsys):
    out = tmp_path / "assets" / "body_model.npz"
    cfg = {"path": str(proxy_body_path), "num_betas": 10, "num_expression": 10}
    assert main(["body-model", "--config-json", json.dumps(cfg), "--out", str(out)]) == 0
    assert out.read_bytes() == proxy_body_path.read_bytes()
    msg = capsys.readouterr().out
    assert "10475 vertices" in msg and "checked copy" in msg


def test_null_path_writes_the_proxy(monkeypatch, proxy_body_path, tmp_path, capsys):
    calls = []

    def fake_write(path, seed=0):  # the real generator is covered by test_proxy.py
        calls.append(seed)
        shutil.copyfile(proxy_body_path, path)
        return path

    monkeypatch.setattr("signsplat.body.proxy.write_proxy_model", fake_write)
    out = tmp_path / "body_model.npz"
    assert main(["body-model", "--config-json", json.dumps({"path": None, "proxy_seed": 4}),
                 "--out", str(out)]) == 0
    assert calls == [4] and out.exists()
    assert "procedural proxy (seed 4)" in capsys.readouterr().out


def test_bad_file_names_the_key(make_fake_arrays, tmp_path, capsys):
    arrays = make_fake_arrays()
    del arrays["weights"]
    bad = tmp_path / "bad.npz"
    np.savez(bad, **arrays)
    out = tmp_path / "out.npz"
    code = main(["body-model", "--config-json", json.dumps({"path": str(bad)}), "--out", str(out)])
    assert code == 2
    err = capsys.readouterr().err
    assert "'weights'" in err and "bad.npz" in err
    assert not out.exists()


def test_bad_config_is_refused(tmp_path, capsys):
    code = main(["body-model", "--config-json", json.dumps({"num_betas": 0}),
                 "--out", str(tmp_path / "x.npz")])
    assert code == 2
    assert "num_betas" in capsys.readouterr().err
