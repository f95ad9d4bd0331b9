"""``signsplat sign``: plan files and the streamed SMPL-X track."""

import json

import pytest

from signsplat.cli import main
from signsplat.io.tables import read_table
from signsplat.motion.clips import write_library


def test_sign_command_writes_plan_and_track(tmp_path, gloss_library):
    lib = write_library(gloss_library.values(), tmp_path / "glosses.parquet")
    out = tmp_path / "stitched"
    rc = main(["sign", "Yesterday I didn't go to school.", "--library", str(lib),
               "--out", str(out), "--id", "demo",
               "--config-json", json.dumps({"min_transition": 4, "max_transition": 8})])
    assert rc == 0
    plan = json.loads((out / "demo.plan.json").read_text())
    assert plan["glosses"] == ["YESTERDAY", "SCHOOL", "ME", "GO", "NOT"]
    assert "coverage:" in (out / "demo.plan.txt").read_text()
    df = read_table(out / "demo.smplx.parquet", "smplx_params")
    labels = list(df.label)
    assert labels[0] == "YESTERDAY" and labels[-1] == "NOT"
    runs = [len(r) for r in "".join("t" if x == "transition" else "g" for x in labels).split("g")
            if r]
    assert len(runs) == 4 and all(4 <= r <= 8 for r in runs)


def test_sign_command_reports_bad_config(tmp_path, gloss_library, capsys):
    lib = write_library(gloss_library.values(), tmp_path / "glosses.parquet")
    rc = main(["sign", "hello", "--library", str(lib), "--out", str(tmp_path),
               "--config-json", '{"deg_per_frame": 0}'])
    assert rc == 2
    assert "deg_per_frame" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["sign", "hello", "--out", str(tmp_path)])  # --library is required
