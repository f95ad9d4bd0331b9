"""Synthetic sequence sheets (`signsplat sheet synth`): N signers x M sentences, valid scenes
that the workflow's sheet loader reads."""

from pathlib import Path

import pytest
import yaml

from signsplat.cli import main
from signsplat.config import load_sequences, validate
from signsplat.errors import SignSplatError
from signsplat.synth.sheet import sign_glosses, synth_sequences, write_sheet

ROOT = Path(__file__).resolve().parents[2]
TINY = yaml.safe_load((ROOT / "config" / "scenes" / "tiny.yaml").read_text())


def _sheet(signers=3, sentences=4, **kw):
    args = dict(seed=0, glosses=(1, 3), cameras=(1, 6), betas_sigma=1.0, num_betas=10)
    args.update(kw)
    return synth_sequences(signers, sentences, TINY, **args)


def test_signers_and_sentences_vary_as_declared():
    specs = _sheet()
    assert len(specs) == 12 and len({s["seed"] for s in specs.values()}) == 12
    by = {(n[3:5], n[-2:]): s for n, s in specs.items()}  # sigII_senJJ
    for (i, j), spec in by.items():
        validate(spec, "scene.schema.yaml", f"{i}/{j}")
        # one body and appearance per signer, one gloss sentence per sentence
        assert spec["signer"] == by[(i, "00")]["signer"]
        assert spec["motion"]["glosses"] == by[("00", j)]["motion"]["glosses"]
        assert 1 <= len(spec["motion"]["glosses"]) <= 3
        assert set(spec["motion"]["glosses"]) <= set(sign_glosses())
        # everything else is the base scene's
        assert spec["cameras"]["width"] == 64 and spec["max_frames"] == 4
    bodies = [by[(i, "00")]["signer"] for i in ("00", "01", "02")]
    assert len({tuple(b["betas"]) for b in bodies}) == 3
    assert len({b["appearance_seed"] for b in bodies}) == 3
    assert len({tuple(by[("00", j)]["motion"]["glosses"]) for j in ("00", "01", "02", "03")}) > 1
    # 12 sequences, counts 1..6 dealt in turn: each count twice
    counts = sorted(s["cameras"]["count"] for s in specs.values())
    assert counts == sorted(list(range(1, 7)) * 2)


def test_same_seed_same_sheet_other_seed_other_sheet():
    assert _sheet(seed=3) == _sheet(seed=3)
    assert _sheet(seed=3) != _sheet(seed=4)


def test_the_workflow_reads_the_written_sheet(tmp_path):
    specs = _sheet(2, 3, cameras=(2, 4))
    sheet = write_sheet(specs, tmp_path / "batch")
    seqs = load_sequences({"sequences": str(sheet), "scenes": []})
    assert list(seqs) == list(specs)
    for name, row in seqs.items():
        assert row["source"] == "synthetic" and row["num_views"] == specs[name]["cameras"]["count"]
        assert 2 <= row["num_views"] <= 4
        assert row["scene"]["signer"]["betas"] == specs[name]["signer"]["betas"]


def test_command_writes_the_sheet_and_names_bad_ranges(tmp_path, capsys):
    out = tmp_path / "s"
    assert main(["sheet", "synth", "--signers", "2", "--sentences", "2", "--out", str(out),
                 "--base", str(ROOT / "config" / "scenes" / "tiny.yaml"), "--frames", "3",
                 "--size", "48", "--cameras", "1", "2"]) == 0
    assert "4 sequences (2 signers x 2 sentences), camera counts [1, 2]" in capsys.readouterr().out
    assert len((out / "sequences.tsv").read_text().splitlines()) == 5
    spec = yaml.safe_load(next((out / "scenes").glob("*.yaml")).read_text())
    assert spec["max_frames"] == 3 and spec["cameras"]["width"] == spec["cameras"]["height_px"] == 48
    with pytest.raises(SignSplatError, match="--cameras 0 6"):
        _sheet(cameras=(0, 6))
    with pytest.raises(SignSplatError, match="--glosses 1 999"):
        _sheet(glosses=(1, 999))
