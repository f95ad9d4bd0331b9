"""Which detectors a sequence uses: the shipped ones for synthetic scenes, the pretrained
real-world ones for footage, a sheet row's `detectors` column over both; the model files each
choice makes the workflow wait for (the pretrained ones are `fetch_models`' outputs)."""

from __future__ import annotations

import pytest

from signsplat.config import ConfigError, load_sequences, validate
from signsplat.perception.cli import detector_files, detectors_for

CFG = validate({}, "stages/perception.schema.yaml")


def _sheet(tmp_path, text):
    path = tmp_path / "seq.tsv"
    path.write_text(text.replace("|", "\t"))
    return {"sequences": str(path), "scenes": []}


def test_defaults_by_source_and_the_sheet_override(tmp_path):
    from signsplat.config import REPO_ROOT

    spec = f"{REPO_ROOT}/config/scenes/studio6.yaml"
    seqs = load_sequences(_sheet(tmp_path, "sequence|source|spec|cameras|detectors\n"
                                 f"s6|synthetic|{spec}||\n"
                                 f"s6p|synthetic|{spec}||pretrained\n"
                                 "clip|video||a.mp4|\n"
                                 "clip_s|video||a.mp4|shipped\n"))
    got = {name: detectors_for(row, CFG) for name, row in seqs.items()}
    assert got == {"s6": "shipped", "s6p": "pretrained", "clip": "pretrained",
                   "clip_s": "shipped"}
    cfg = validate({"detectors": {"video": "shipped"}}, "stages/perception.schema.yaml")
    assert detectors_for(seqs["clip"], cfg) == "shipped"


def test_unknown_detectors_value_names_the_line(tmp_path):
    with pytest.raises(ConfigError, match=r"line 2.*'detectors'.*'shipped', 'pretrained'"):
        load_sequences(_sheet(tmp_path, "sequence|source|cameras|detectors\nx|video|a.mp4|rtmw\n"))


def test_files_each_choice_reads():
    shipped = detector_files(CFG, "shipped")
    assert shipped == {"segmenter": ["models/segmenter.onnx"],
                       "keypoints": ["models/keypoints.onnx"]}
    pre = detector_files(CFG, "pretrained")
    assert pre["segmenter"] == ["models/cache/modnet.onnx"]
    assert len(pre["keypoints"]) == 6 and all(f.startswith("models/cache/") and f.endswith(".onnx")
                                              for f in pre["keypoints"])
