"""Which detectors a sequence uses: the shipped ones for synthetic scenes, the pretrained
real-world ones for footage, a sheet row's `detectors` column over both; the model files each
choice makes the workflow wait for (the pretrained ones are the outputs of `fetch_modnet`
and `fetch_mediapipe`, one rule per wheel)."""

from __future__ import annotations

import pytest

from signsplat.config import ConfigError, load_sequences, validate
from signsplat.perception.detectors import (asset_files, detector_files, detectors_for,
                                           perception_for, segment_section)

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
                                 "clip_s|video||a.mp4|shipped\n"
                                 f"ring|synthetic|{spec}||wide\n"))
    got = {name: detectors_for(row, CFG) for name, row in seqs.items()}
    assert got == {"s6": "shipped", "s6p": "pretrained", "clip": "pretrained",
                   "clip_s": "shipped", "ring": "wide"}
    cfg = validate({"detectors": {"video": "shipped"}}, "stages/perception.schema.yaml")
    assert detectors_for(seqs["clip"], cfg) == "shipped"


def test_unknown_detectors_value_names_the_line(tmp_path):
    with pytest.raises(ConfigError,
                       match=r"line 2.*'detectors'.*'shipped', 'wide', 'pretrained'"):
        load_sequences(_sheet(tmp_path, "sequence|source|cameras|detectors\nx|video|a.mp4|rtmw\n"))


def test_the_dominant_hand_s_fingers_come_from_mediapipe(tmp_path):
    """keypoints.hands `dominant` (the default): a row's dominant_hand takes MediaPipe's
    fingers on that side, on one camera too with the model's hand crops (the default); with
    the pose's crops only on several cameras; no dominant hand keeps the model's; the fit
    then applies the pretrained table's finger rows of that side; `model` and `mediapipe`
    ignore the column."""
    from signsplat.config import REPO_ROOT
    from signsplat.fit.keypoint_offsets import fit_offsets

    six, one = (f"{REPO_ROOT}/config/scenes/{n}.yaml" for n in ("studio6", "single"))
    seqs = load_sequences(_sheet(tmp_path, "sequence|source|spec|dominant_hand\n"
                                 f"six_r|synthetic|{six}|right\n"
                                 f"six_l|synthetic|{six}|left\n"
                                 f"six|synthetic|{six}|\n"
                                 f"one_r|synthetic|{one}|right\n"))
    assert CFG["keypoints"]["hands"] == "dominant" and CFG["keypoints"]["hand_crop"] == "model"
    pose = {**CFG, "keypoints": {**CFG["keypoints"], "hand_crop": "pose"}}
    got = {}
    for crop, cfg in (("model", CFG), ("pose", pose)):
        for n, row in seqs.items():
            k = perception_for(row, cfg)["keypoints"]
            got[crop, n] = (k["hands"], k["hand_sides"] if k["hands"] == "mediapipe" else None)
    assert got == {("model", "six_r"): ("mediapipe", ["right"]),
                   ("model", "six_l"): ("mediapipe", ["left"]),
                   ("model", "six"): ("model", None),
                   ("model", "one_r"): ("mediapipe", ["right"]),
                   ("pose", "six_r"): ("mediapipe", ["right"]),
                   ("pose", "six_l"): ("mediapipe", ["left"]),
                   ("pose", "six"): ("model", None),
                   ("pose", "one_r"): ("model", None)}
    assert CFG["keypoints"]["hands"] == "dominant"  # the shared section is left as it was
    files = {n: detector_files(perception_for(row, CFG), "shipped")["keypoints"]
             for n, row in seqs.items()}
    assert "models/cache/hand_landmark_full.onnx" in files["six_r"]
    assert files["one_r"] == files["six_r"]
    assert files["six"] == ["models/keypoints.onnx"]
    fit = {"keypoints": "detected", "keypoint_offsets": {
        "shipped": None, "wide": None, "pretrained": "p.parquet"}}
    keypoints = {n: perception_for(row, CFG)["keypoints"] for n, row in seqs.items()}
    assert fit_offsets(fit, "shipped", keypoints["six_l"]) == ("p.parquet", ("left",))
    assert fit_offsets(fit, "shipped", keypoints["one_r"]) == ("p.parquet", ("right",))
    assert fit_offsets(fit, "shipped", keypoints["six"]) == (None, ())
    for hands in ("model", "mediapipe"):
        cfg = validate({"keypoints": {"hands": hands}}, "stages/perception.schema.yaml")
        assert perception_for(seqs["six_r"], cfg) is cfg
    with pytest.raises(ConfigError, match=r"line 2.*'dominant_hand'.*'left', 'right'"):
        load_sequences(_sheet(tmp_path, "sequence|source|cameras|dominant_hand\n"
                                        "x|video|a.mp4|both\n"))


def test_the_segment_stage_s_section_leaves_the_keypoints_out():
    """The segment stage's parameters: a keypoint setting or a sheet's dominant hand leaves
    them (and so the masks) as they are; the segmenter's and the signer's settings do not.
    The section alone is a whole perception section once validated (the command fills in
    the rest from the schema)."""
    seg = segment_section(CFG)
    assert "keypoints" not in seg and "eval" not in seg
    six_right = {"dominant_hand": "right", "num_views": 6}
    assert perception_for(six_right, CFG)["keypoints"] != CFG["keypoints"]
    assert segment_section(perception_for(six_right, CFG)) == seg
    assert segment_section({**CFG, "keypoints": {**CFG["keypoints"], "batch_size": 3}}) == seg
    assert segment_section(perception_for({"signer": "central"}, CFG)) != seg
    threshold = {**CFG, "segmenter": {**CFG["segmenter"], "threshold": 0.1}}
    assert segment_section(threshold) != seg
    assert validate(seg, "stages/perception.schema.yaml") == CFG


def test_files_each_choice_reads():
    landmarker = [f"models/cache/{name}.onnx" for name in (
        "pose_detection", "pose_landmark_full", "hand_recrop", "hand_landmark_full",
        "palm_detection_full", "face_detection_short_range", "face_landmark")]
    assert detector_files(CFG, "shipped") == {"segmenter": ["models/segmenter.onnx"],
                                              "keypoints": ["models/keypoints.onnx"]}
    assert detector_files(CFG, "wide") == {"segmenter": ["models/segmenter.onnx"],
                                           "keypoints": ["models/keypoints_wide.onnx"]}
    # with MediaPipe's hands the shipped and wide keypointers read its hand model too (in the
    # model's crops, the default), or the models its pose chain runs (in the pose's crops)
    mp = {**CFG, "keypoints": {**CFG["keypoints"], "hands": "mediapipe"}}
    hand = ["models/cache/hand_landmark_full.onnx"]
    assert detector_files(mp, "shipped")["keypoints"] == ["models/keypoints.onnx", *hand]
    assert detector_files(mp, "wide")["keypoints"] == ["models/keypoints_wide.onnx", *hand]
    pose = {**mp, "keypoints": {**mp["keypoints"], "hand_crop": "pose"}}
    assert detector_files(pose, "shipped")["keypoints"] == ["models/keypoints.onnx", *landmarker]
    pre = detector_files(CFG, "pretrained")
    assert pre["segmenter"] == ["models/cache/modnet.onnx"]
    assert pre["keypoints"] == landmarker
    # the example clip is a fetched asset in the same cache (the fetch_assets rule makes it)
    moved = {**CFG, "pretrained": {**CFG["pretrained"], "cache": "/elsewhere"}}
    assert asset_files(moved) == {"demovideo": "/elsewhere/demovideo.mp4"}


def test_specs_carry_the_stage_device_and_no_defaults_of_their_own(tmp_path):
    """The stage's --device reaches every model spec (onnxruntime providers follow it); the
    MediaPipe spec takes its settings from the schema only."""
    import dataclasses

    from signsplat.perception.detectors import detector_specs
    from signsplat.perception.pretrained.keypointer import MediaPipeSpec

    cfg = {**CFG, "pretrained": {**CFG["pretrained"], "cache": str(tmp_path)}}
    open(detector_files(cfg, "pretrained")["segmenter"][0], "wb").close()  # model_file checks
    for detectors in ("shipped", "wide", "pretrained"):
        seg, kp = detector_specs(cfg, detectors, "cpu")
        assert seg.device == "cpu" and kp.device == "cpu", detectors
    assert detector_specs(cfg, "wide")[1].path == "models/keypoints_wide.onnx"
    assert detector_specs(cfg, "wide")[0] == detector_specs(cfg, "shipped")[0]
    mp = {**cfg, "keypoints": {**cfg["keypoints"], "hands": "mediapipe"}}
    _, kp = detector_specs(mp, "wide", "cuda:1")
    assert kp.base.path == "models/keypoints_wide.onnx" and kp.device == "cuda:1"
    assert kp.hands.device == "cuda:1" and kp.hands.face is False
    assert kp.reach == CFG["keypoints"]["hand_reach"]
    assert kp.sides == kp.hands.hand_sides == tuple(CFG["keypoints"]["hand_sides"])
    one = {**mp, "keypoints": {**mp["keypoints"], "hand_sides": ["right"]}}
    assert detector_specs(one, "shipped")[1].hands.hand_sides == ("right",)
    _, kp = detector_specs(cfg, "pretrained", "cuda:1")
    assert kp.device == "cuda:1" and kp.track is CFG["pretrained"]["keypoints"]["track"]
    assert kp.hand_sides == ("left", "right")  # the whole body: both hands
    assert [f.name for f in dataclasses.fields(MediaPipeSpec)
            if f.default is not dataclasses.MISSING] == []


def test_mediapipe_sessions_open_on_the_spec_device(tmp_path, monkeypatch):
    from types import SimpleNamespace

    from signsplat.perception.pretrained import keypointer as kpr

    seen = []

    def fake_session(path, threads, what, device):
        seen.append(device)
        size = next(m["size"] for m in kpr.MODELS if m["name"] in what)
        return SimpleNamespace(get_inputs=lambda: [SimpleNamespace(shape=[1, 3, size, size])])

    monkeypatch.setattr(kpr, "open_session", fake_session)
    monkeypatch.setattr(kpr, "model_file", lambda cache, name: tmp_path / f"{name}.onnx")
    spec = kpr.MediaPipeSpec.from_config(CFG["pretrained"], device="cuda:1")
    kpr.MediaPipeWholeBody(spec, threads=1)
    assert seen == ["cuda:1"] * len(kpr.MODELS)
