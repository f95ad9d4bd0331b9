"""Which detectors a sequence runs with, and their model specs.

Each sequence uses the shipped detectors (``models/*.onnx``, trained on simulated scenes), the
shipped segmenter with the keypoint model adapted to other rigs (``wide``:
``perception.keypoints.wide_model``), or the pretrained real-world ones (MODNet and
MediaPipe's models, fetched by ``signsplat models fetch`` into ``perception.pretrained.cache``):
``perception.detectors`` by the sheet row's source, or the row's own ``detectors`` column.
The workflow asks this module for a sequence's choice, its perception section (the row's
``signer`` and ``dominant_hand`` columns applied) and the model files its rules read; the
stage commands ask it for the specs.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path

from signsplat.perception.contracts import KeypointSpec, SegmenterSpec

# MODNet's input normalisation (v - 127.5) / 127.5: a fact of the model (manifest), not a setting
MODNET_MEAN_STD = (127.5, 127.5, 127.5)
DETECTORS = ("shipped", "wide", "pretrained")


def specs(cfg: dict, device: str = "auto") -> tuple[SegmenterSpec, KeypointSpec]:
    """The shipped detectors' specs from a validated ``perception`` section, on ``device``."""
    s, k = cfg["segmenter"], cfg["keypoints"]
    seg = SegmenterSpec(
        path=s["model"], input_size=tuple(s["input_size"]) if s["input_size"] else None,
        mean=tuple(s["mean"]), std=tuple(s["std"]), color_order=s["color_order"],
        output_index=s["output_index"], threshold=s["threshold"], batch_size=s["batch_size"],
        device=device)
    kp = KeypointSpec(
        path=k["model"], input_size=tuple(k["input_size"]) if k["input_size"] else None,
        mean=tuple(k["mean"]), std=tuple(k["std"]), color_order=k["color_order"],
        split_ratio=float(k["split_ratio"]), padding=float(k["padding"]),
        score_mode=k["score_mode"], min_area=k["min_area"], batch_size=k["batch_size"],
        device=device)
    return seg, kp


def pretrained_specs(cfg: dict, device: str = "auto"):
    """(SegmenterSpec, MediaPipeSpec) of the pretrained detectors from a validated
    ``perception`` section, on ``device``; model files are read from ``pretrained.cache`` (a
    missing one fails with how to fetch it)."""
    from signsplat.perception.pretrained.fetch import model_file
    from signsplat.perception.pretrained.keypointer import MediaPipeSpec

    pre = cfg["pretrained"]
    s = pre["segmenter"]
    seg = SegmenterSpec(
        path=str(model_file(pre["cache"], "modnet")), input_size=None,
        mean=MODNET_MEAN_STD, std=MODNET_MEAN_STD, color_order="rgb", output_index=0,
        threshold=s["threshold"], batch_size=s["batch_size"], reference_size=s["reference_size"],
        device=device)
    return seg, MediaPipeSpec.from_config(pre, device=device)


def detector_specs(cfg: dict, detectors: str, device: str = "auto"):
    """(segmenter spec, keypointer spec) for ``detectors`` (one of :data:`DETECTORS`); the
    shipped and ``wide`` keypointers with ``keypoints.hands: mediapipe`` are a
    :class:`~signsplat.perception.hands.HandsSpec`."""
    if detectors == "pretrained":
        return pretrained_specs(cfg, device)
    seg, kp = specs(cfg, device)
    k = cfg["keypoints"]
    if detectors == "wide":
        kp = dataclasses.replace(kp, path=k["wide_model"])
    if k["hands"] == "mediapipe":
        from signsplat.perception.hands import HandsSpec
        from signsplat.perception.pretrained.keypointer import MediaPipeSpec

        sides = tuple(k["hand_sides"])
        landmarker = MediaPipeSpec.from_config(cfg["pretrained"], device=device, face=False,
                                               hand_sides=sides)
        kp = HandsSpec(base=kp, hands=landmarker, min_score=k["hand_min_score"],
                       reach=k["hand_reach"], sides=sides, crop=k["hand_crop"])
    return seg, kp


def detectors_for(row: dict, cfg: dict) -> str:
    """One of :data:`DETECTORS` for one sequence-sheet row: its ``detectors`` column when
    set, else ``perception.detectors`` by the row's source (synthetic / video)."""
    return row.get("detectors") or cfg["detectors"][row["source"]]


def perception_for(row: dict, cfg: dict) -> dict:
    """The perception section one sequence runs with: ``cfg`` with the row's ``signer``
    column (largest, central or x,y,w,h) in place of ``signer.rule`` / ``signer.box``, and
    with ``keypoints.hands: dominant`` that choice made for the row (:func:`hands_for`)."""
    if cfg["keypoints"]["hands"] == "dominant":
        k = cfg["keypoints"]
        cfg = {**cfg, "keypoints": {**k, **hands_for(row, k["hand_crop"])}}
    if not row.get("signer"):
        return cfg
    from signsplat.perception.pretrained.select import parse_signer

    return {**cfg, "signer": {**cfg["signer"], **parse_signer(row["signer"])}}


#: what the segment stage reads of a perception section (the keypoint model's settings, the
#: evaluation's and the training's do not change its masks)
SEGMENT_KEYS = ("skip_bad_frames", "segmenter", "pretrained", "signer")


def segment_section(cfg: dict) -> dict:
    """The part of a perception section the segment stage reads (:data:`SEGMENT_KEYS`): its
    workflow parameters, so that a keypoint setting (or a sheet's ``dominant_hand``) does not
    make the masks again."""
    return {k: cfg[k] for k in SEGMENT_KEYS}


def hands_for(row: dict, crop: str) -> dict:
    """``keypoints.hands: dominant`` for one sheet row: MediaPipe's fingers on the row's
    ``dominant_hand`` (``hands: mediapipe``, ``hand_sides: [that side]``), the keypoint
    model's own fingers where no dominant hand is given. With ``crop`` (``hand_crop``) `pose`
    only on sequences with several cameras: in the pose's crops MediaPipe's hand is often
    mirrored, which one camera cannot outvote (``docs/avatar.md``)."""
    side = row.get("dominant_hand")
    if side and (crop == "model" or row.get("num_views", 1) > 1):
        return {"hands": "mediapipe", "hand_sides": [side]}
    return {"hands": "model"}


def detector_files(cfg: dict, detectors: str) -> dict[str, list[str]]:
    """The model files each stage reads for ``detectors`` (workflow inputs): the configured
    ONNX files, or the pretrained ones in ``perception.pretrained.cache`` (also MediaPipe's
    keypoint models for the shipped and ``wide`` keypointers with ``keypoints.hands:
    mediapipe``: its hand landmark model alone with ``hand_crop: model``)."""
    if detectors == "pretrained":
        fetched = pretrained_files(cfg)
        return {"segmenter": list(fetched["modnet"].values()),
                "keypoints": list(fetched["mediapipe"].values())}
    k = cfg["keypoints"]
    model = k["wide_model" if detectors == "wide" else "model"]
    hands = []
    if k["hands"] == "mediapipe":
        from signsplat.perception.pretrained.graphs import HAND_LMK

        landmarker = pretrained_files(cfg)["mediapipe"]
        hands = ([landmarker[HAND_LMK["name"]]] if k["hand_crop"] == "model"
                 else list(landmarker.values()))
    return {"segmenter": [cfg["segmenter"]["model"]], "keypoints": [model, *hands]}


def pretrained_files(cfg: dict) -> dict[str, dict[str, str]]:
    """The pretrained models in ``pretrained.cache`` by the wheel they are fetched from
    (``modnet``: MODNet; ``mediapipe``: MediaPipe's keypoint models), each as manifest name ->
    path (read from the manifest, which the shipped detectors without MediaPipe's hands never
    need)."""
    from signsplat.perception.pretrained.fetch import load_manifest
    from signsplat.perception.pretrained.graphs import MODELS

    cache = Path(cfg["pretrained"]["cache"])
    _, entries = load_manifest()
    return {"modnet": {"modnet": str(cache / entries["modnet"].target)},
            "mediapipe": {m["name"]: str(cache / entries[m["name"]].target) for m in MODELS}}


def asset_files(cfg: dict) -> dict[str, str]:
    """Fetchable assets (the example clip) by name -> their path in the cache."""
    from signsplat.perception.pretrained.fetch import load_manifest

    _, entries = load_manifest()
    return {n: str(Path(cfg["pretrained"]["cache"]) / e.target)
            for n, e in entries.items() if e.kind == "asset"}
