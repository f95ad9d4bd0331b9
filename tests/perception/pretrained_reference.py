"""Reference outputs of MediaPipe's own runtimes, produced once and committed as numbers
(``data/pretrained_reference.npz``), against which the converted models and our pipeline are
tested.

- ``raw``: each TFLite model run by the TFLite runtime (``ai-edge-litert``) on fixed crops of
  scikit-image's astronaut photo (inputs rebuilt by :func:`model_inputs`, never stored).
- ``holistic``: MediaPipe Holistic 0.10.21 (model complexity 1, static images) on the
  astronaut photo and the synthetic test frame ``data/single_v00_f0040.png``: pose (33 x, y,
  visibility), hands (21 x, y), face mesh (468 x, y) in pixels.

Run once (each part in an environment that has its runtime; the second needs the astronaut
photo saved as PNG, since that environment lacks scikit-image)::

    python tests/perception/pretrained_reference.py raw
    /path/to/venv-with-mediapipe/bin/python tests/perception/pretrained_reference.py \\
        holistic --astronaut astronaut.png
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

DATA = Path(__file__).parent / "data"
OUT = DATA / "pretrained_reference.npz"
SYNTHETIC = "single_v00_f0040"

# Fixed regions of the 512 x 512 astronaut photo (centre x, y, side, rotation) per model.
ROIS = {
    "pose_detection": (256.0, 256.0, 512.0, 0.0),
    "pose_landmark_full": (210.0, 330.0, 560.0, 0.15),
    "hand_recrop": (205.0, 470.0, 150.0, 0.3),
    "hand_landmark_full": (205.0, 465.0, 110.0, -0.2),
    "palm_detection_full": (205.0, 460.0, 200.0, 0.0),
    "face_detection_short_range": (225.0, 125.0, 260.0, 0.0),
    "face_landmark": (224.0, 125.0, 130.0, 0.08),
}
SIZES = {"pose_detection": 224, "pose_landmark_full": 256, "hand_recrop": 256,
         "hand_landmark_full": 224, "palm_detection_full": 192, "face_detection_short_range": 128,
         "face_landmark": 192}
RANGES = {"pose_detection": (-1.0, 1.0), "face_detection_short_range": (-1.0, 1.0)}
ZERO_BORDER = ("pose_detection", "palm_detection_full", "face_detection_short_range")


def model_inputs(image: np.ndarray) -> dict[str, np.ndarray]:
    """(1, 3, S, S) float32 input per model: a crop of ``image`` (RGB uint8)."""
    from signsplat.perception.pretrained import mediapipe as mp

    out = {}
    for name, (cx, cy, side, rot) in ROIS.items():
        s = SIZES[name]
        out[name] = mp.crop(image, mp.Roi(cx, cy, side, side, rot), (s, s),
                            RANGES.get(name, (0.0, 1.0)), "zero" if name in ZERO_BORDER else "replicate")
    return out


def summarise(name: str, outs: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """The stored part of a model's raw outputs (NHWC arrays as the TFLite runtime gives
    them): small outputs whole, detector boxes of the 10 best anchors, heatmap maxima."""
    if name in ("pose_detection", "palm_detection_full", "face_detection_short_range"):
        boxes, scores = (outs["regressors"], outs["classificators"]) \
            if name == "face_detection_short_range" else (outs["Identity"], outs["Identity_1"])
        scores = scores.reshape(-1)
        top = np.argsort(-scores)[:10]
        return {"scores": scores, "top": top, "top_boxes": boxes.reshape(len(scores), -1)[top]}
    if name == "pose_landmark_full":
        return {"landmarks": outs["Identity"].ravel(), "presence": outs["Identity_1"].ravel(),
                "heatmap_max": outs["Identity_3"].reshape(-1, 39).max(0),
                "world": outs["Identity_4"].ravel()}
    if name == "hand_landmark_full":
        return {"landmarks": outs["Identity"].ravel(), "presence": outs["Identity_1"].ravel(),
                "handedness": outs["Identity_2"].ravel(), "world": outs["Identity_3"].ravel()}
    if name == "face_landmark":
        return {"landmarks": outs["conv2d_21"].ravel(), "presence": outs["conv2d_31"].ravel()}
    if name == "hand_recrop":
        return {"points": outs["output_crop"].ravel()}
    raise KeyError(name)


def _raw(tflite_dir: Path) -> dict[str, np.ndarray]:
    import skimage.data
    from ai_edge_litert.interpreter import Interpreter

    inputs = model_inputs(skimage.data.astronaut())
    out = {}
    for name, x in inputs.items():
        it = Interpreter(str(tflite_dir / f"{name}.tflite"))
        it.allocate_tensors()
        it.set_tensor(it.get_input_details()[0]["index"], x.transpose(0, 2, 3, 1).copy())
        it.invoke()
        outs = {d["name"]: it.get_tensor(d["index"]) for d in it.get_output_details()}
        for key, val in summarise(name, outs).items():
            out[f"raw/{name}/{key}"] = np.asarray(val)
    return out


def _holistic(images: dict[str, Path]) -> dict[str, np.ndarray]:
    import cv2
    import mediapipe as mpipe

    out = {}
    for tag, path in images.items():
        img = cv2.cvtColor(cv2.imread(str(path)), cv2.COLOR_BGR2RGB)
        h, w = img.shape[:2]
        with mpipe.solutions.holistic.Holistic(static_image_mode=True, model_complexity=1) as m:
            r = m.process(img)
        for key in ("pose_landmarks", "left_hand_landmarks", "right_hand_landmarks",
                    "face_landmarks"):
            lms = getattr(r, key)
            if lms is not None:
                out[f"holistic/{tag}/{key}"] = np.array(
                    [[p.x * w, p.y * h, p.visibility] for p in lms.landmark], np.float32)
    return out


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__)
    p.add_argument("part", choices=["raw", "holistic"])
    p.add_argument("--tflite-dir", default="models/cache/src/mediapipe-0.10.21")
    p.add_argument("--astronaut", help="the astronaut photo as PNG (holistic part)")
    a = p.parse_args()
    old = dict(np.load(OUT)) if OUT.exists() else {}
    if a.part == "raw":
        new = _raw(Path(a.tflite_dir))
    else:
        new = _holistic({"astronaut": Path(a.astronaut), "synthetic": DATA / f"{SYNTHETIC}.png"})
    old = {k: v for k, v in old.items() if not k.startswith(a.part + "/")}
    np.savez_compressed(OUT, **old, **{k: v.astype(np.float32) if v.dtype.kind == "f" else v
                                       for k, v in new.items()})
    print(f"{OUT}: {len(new)} arrays for part {a.part}")


if __name__ == "__main__":
    main()
