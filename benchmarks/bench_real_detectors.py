"""The pretrained real-world detectors: fidelity of the conversion, speed, and accuracy on the
simulator's ground truth beside the shipped models.

Usage: python benchmarks/bench_real_detectors.py [--scenes studio6 single] [--results results]
       [--threads 1] [--out benchmarks/results/real_detectors.parquet]

1. Fidelity: the keypointer runs on real images (scikit-image's astronaut photo and, when
   fetched, 20 frames of the example clip); every crop it feeds a converted model is also fed
   to the source TFLite model in the TFLite runtime (``ai-edge-litert``; skipped when not
   installed). Rows: max absolute raw-output difference per model and output, and that
   difference relative to the output's largest magnitude.
2. Speed: frames/s of the whole-body keypointer over a scene's frames in time order (tracking
   on, as the stage runs it) and of MODNet at the sizes the stage feeds it (a 256 x 256
   synthetic frame -> 512 x 512; a 1080 x 720 clip frame -> 768 x 512), one thread.
3. Accuracy: both detector sets (each with its own masks) on the simulated scenes
   (``results/<scene>/sim``, simulated into a temporary folder when absent): mask IoU and
   PCK@0.05 per part (signsplat.perception.evaluate), plus PCK per body keypoint.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import pandas as pd

from signsplat.body.joints import COCO_BODY_NAMES
from signsplat.config import REPO_ROOT, validate
from signsplat.io.atomic import atomic_path
from signsplat.io.images import read_mask, read_rgb
from signsplat.io.tables import read_table
from signsplat.perception.contracts import load_segmenter
from signsplat.perception.detectors import pretrained_specs, specs
from signsplat.perception.evaluate import PCK_ALPHA, accuracy
from signsplat.perception.keypoints import box_from_mask
from signsplat.perception.pretrained.keypointer import MODELS, MediaPipeSpec, MediaPipeWholeBody
from signsplat.perception.segment import segment_batch
from signsplat.perception.stages import detect_sequence, segment_sequence

COLUMNS = ["section", "detectors", "scene", "metric", "part", "value", "count"]


def _row(section, detectors, scene, metric, part, value, count=0):
    return dict(section=section, detectors=detectors, scene=scene, metric=metric, part=part,
                value=float(value), count=int(count))


def _real_images(cache: Path) -> list[np.ndarray]:
    import skimage.data

    images = [skimage.data.astronaut()]
    clip = cache / "demovideo.mp4"
    if clip.is_file():
        from signsplat.io.video import iter_frames

        images += [f for i, f in iter_frames(clip, 0, 200) if i % 10 == 0]
    return images


def fidelity(spec: MediaPipeSpec, images: list[np.ndarray]) -> list[dict]:
    """Converted ONNX vs the source TFLite model on the crops the keypointer makes."""
    try:
        from ai_edge_litert.interpreter import Interpreter
    except ImportError:
        print("fidelity: ai-edge-litert not installed (pip install ai-edge-litert==2.3.0); "
              "skipped", file=sys.stderr)
        return []
    kp = MediaPipeWholeBody(spec, threads=1)
    seen: dict[str, list[np.ndarray]] = {m["name"]: [] for m in MODELS}

    class Recording:
        """An onnxruntime session that keeps every input it is given."""

        def __init__(self, sess, store):
            self.sess, self.store = sess, store

        def get_inputs(self):
            return self.sess.get_inputs()

        def run(self, names, feed):
            self.store.append(next(iter(feed.values())).copy())
            return self.sess.run(names, feed)

    sessions = dict(kp.sessions)
    kp.sessions = {n: Recording(s, seen[n]) for n, s in sessions.items()}
    for img in images:
        kp.reset()
        kp.detect(img)
    rows = []
    src = Path(spec.cache) / "src" / "mediapipe-0.10.21"
    for name, inputs in seen.items():
        if not inputs:
            continue
        it = Interpreter(str(src / f"{name}.tflite"))
        it.allocate_tensors()
        sess = sessions[name]
        worst: dict[str, list[float]] = {}
        for x in inputs:
            it.set_tensor(it.get_input_details()[0]["index"], x.transpose(0, 2, 3, 1).copy())
            it.invoke()
            ref = {d["name"]: it.get_tensor(d["index"]) for d in it.get_output_details()}
            outs = sess.run(None, {sess.get_inputs()[0].name: x})
            for o, v in zip(sess.get_outputs(), outs):
                r = ref[o.name]
                v = v.transpose(0, 2, 3, 1) if v.ndim == 4 else v
                d = float(np.abs(v.reshape(r.shape) - r).max())
                w = worst.setdefault(o.name, [0.0, 0.0])
                w[0] = max(w[0], d)
                w[1] = max(w[1], float(np.abs(r).max()))
        for out, (d, mag) in worst.items():
            rows.append(_row("fidelity", "pretrained", "real", "max_abs_diff", f"{name}/{out}",
                             d, len(inputs)))
            rows.append(_row("fidelity", "pretrained", "real", "max_rel_diff", f"{name}/{out}",
                             d / max(mag, 1e-12), len(inputs)))
    return rows


def speed(spec: MediaPipeSpec, seg, sim: Path, cache: Path, frames: int = 60) -> list[dict]:
    rows = []
    fr = read_table(sim / "frames.parquet", "frames")
    fr = fr[fr["view"] == fr["view"].min()].sort_values("frame").head(frames)
    images = [read_rgb(sim / p) for p in fr["image"]]
    kp = MediaPipeWholeBody(spec, threads=1)
    kp.detect(images[0])  # warm up
    best = np.inf
    for _ in range(2):
        kp.reset()
        t = time.perf_counter()
        for img in images:
            kp.detect(img)
        best = min(best, time.perf_counter() - t)
    rows.append(_row("speed", "pretrained", sim.parent.name, "fps", "keypoints",
                     len(images) / best, len(images)))
    model = load_segmenter(seg, 1)
    clip = cache / "demovideo.mp4"
    sizes = {"256x256": images[0]}
    if clip.is_file():
        from signsplat.io.video import iter_frames

        sizes["1080x720"] = next(iter(iter_frames(clip, 0, 1)))[1]
    for label, img in sizes.items():
        segment_batch(model, seg, [img])
        best = np.inf
        for _ in range(3):
            t = time.perf_counter()
            for _ in range(5):
                segment_batch(model, seg, [img])
            best = min(best, (time.perf_counter() - t) / 5)
        rows.append(_row("speed", "pretrained", label, "fps", "segment", 1.0 / best, 5))
    return rows


def _simulate(name: str, root: Path) -> Path:
    from signsplat.body.proxy import write_proxy_model
    from signsplat.config import load_scene
    from signsplat.synth.glosses import write_gloss_library
    from signsplat.synth.simulate import simulate_scene

    body, glosses = root / "body.npz", root / "glosses.parquet"
    if not body.exists():
        write_proxy_model(body, seed=0)
        write_gloss_library(glosses, seed=0, fps=25.0)
    spec = load_scene(REPO_ROOT / "config" / "scenes" / f"{name}.yaml")
    spec["name"] = name
    sim = root / name / "sim"
    simulate_scene(validate(spec, "scene.schema.yaml", name), body, glosses, sim, threads=2,
                   progress=False)
    return sim


def body_keypoint_pck(sim: Path, out: Path) -> dict[str, float]:
    gt = read_table(sim / "keypoints_gt.parquet", "keypoints")
    kp = read_table(out / "keypoints.parquet", "keypoints")
    fr = read_table(sim / "frames.parquet", "frames")
    size = {}
    for _, r in fr.iterrows():
        b = box_from_mask(read_mask(sim / r["mask"]))
        size[(r["view"], r["frame"])] = np.nan if b is None else max(b[2] - b[0], b[3] - b[1])
    m = gt.merge(kp, on=["view", "frame", "kp"], suffixes=("_gt", ""))
    m = m[m["visible"] & (m["kp"] < len(COCO_BODY_NAMES))]
    thr = PCK_ALPHA * np.array([size[(v, f)] for v, f in zip(m["view"], m["frame"])])
    err = np.hypot(m["x"] - m["x_gt"], m["y"] - m["y_gt"]).to_numpy()
    hit = np.nan_to_num(err, nan=np.inf) <= thr
    return {COCO_BODY_NAMES[k]: float(hit[m["kp"].to_numpy() == k].mean())
            for k in sorted(m["kp"].unique())}


def accuracy_rows(scene: str, sim: Path, work: Path, detector_sets: dict, threads: int) -> list:
    rows = []
    for label, (seg, kp) in detector_sets.items():
        out = work / label / scene
        t0 = time.perf_counter()
        segment_sequence(sim / "frames.parquet", out, seg, threads, progress=False)
        t1 = time.perf_counter()
        detect_sequence(sim / "frames.parquet", out / "masks.parquet",
                        out / "keypoints.parquet", kp, threads, progress=False, min_area=50)
        t2 = time.perf_counter()
        n = len(read_table(sim / "frames.parquet", "frames"))
        for _, r in accuracy(sim, out).iterrows():
            rows.append(_row("accuracy", label, scene, r["metric"], r["part"], r["value"],
                             r["count"]))
        for part, v in body_keypoint_pck(sim, out).items():
            rows.append(_row("accuracy", label, scene, f"pck@{PCK_ALPHA:g}", f"body:{part}", v))
        rows.append(_row("accuracy", label, scene, "stage_seconds", "segment", t1 - t0, n))
        rows.append(_row("accuracy", label, scene, "stage_seconds", "keypoints", t2 - t1, n))
        print(f"{scene} {label}: segment {t1 - t0:.0f} s, keypoints {t2 - t1:.0f} s ({n} frames)",
              file=sys.stderr, flush=True)
    return rows


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--scenes", nargs="+", default=["studio6", "single"])
    p.add_argument("--results", default="results", help="workflow results with <scene>/sim")
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--skip", nargs="*", default=[], choices=["fidelity", "speed", "accuracy"])
    p.add_argument("--out", default="benchmarks/results/real_detectors.parquet")
    a = p.parse_args()
    cfg = validate({}, "stages/perception.schema.yaml")
    cfg["pretrained"]["cache"] = str(REPO_ROOT / cfg["pretrained"]["cache"])
    cache = Path(cfg["pretrained"]["cache"])
    pseg, pkp = pretrained_specs(cfg)
    sseg, skp = specs(cfg)
    sseg = type(sseg)(**{**sseg.__dict__, "path": str(REPO_ROOT / sseg.path)})
    skp = type(skp)(**{**skp.__dict__, "path": str(REPO_ROOT / skp.path)})
    rows = []
    if "fidelity" not in a.skip:
        rows += fidelity(pkp, _real_images(cache))
    with tempfile.TemporaryDirectory() as tmp:
        sims = {}
        for scene in a.scenes:
            sim = Path(a.results) / scene / "sim"
            sims[scene] = sim if (sim / "keypoints_gt.parquet").exists() \
                else _simulate(scene, Path(tmp))
        if "speed" not in a.skip:
            rows += speed(pkp, pseg, sims[a.scenes[0]], cache)
        if "accuracy" not in a.skip:
            for scene, sim in sims.items():
                rows += accuracy_rows(scene, sim, Path(tmp) / "out",
                                      {"pretrained": (pseg, pkp), "shipped": (sseg, skp)},
                                      a.threads)
    df = pd.DataFrame(rows, columns=COLUMNS)
    with pd.option_context("display.width", 160, "display.max_rows", 500):
        print(df.to_string(index=False, float_format=lambda v: f"{v:.4g}"))
    with atomic_path(a.out) as tmp_out:
        df.to_parquet(tmp_out, index=False)
    print(f"saved {a.out}")


if __name__ == "__main__":
    main()
