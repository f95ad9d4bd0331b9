"""Commands of the perception stages: ``segment``, ``detect-keypoints``, ``perception-eval``,
``perception-quality``, ``train-detectors``. Each takes the ``perception`` config section as
JSON (``--config-json``; missing keys get the schema defaults) and ``--detectors`` (shipped or
pretrained; :mod:`signsplat.perception.detectors`)."""

from __future__ import annotations

import argparse
import json
from concurrent.futures import ProcessPoolExecutor
from multiprocessing import get_context
from pathlib import Path

from signsplat.config import config_option
from signsplat.device import add_runtime_args
from signsplat.io.tables import write_table
from signsplat.perception.detectors import DETECTORS, detector_specs, specs

SCHEMA = "stages/perception.schema.yaml"


def perception_config(text: str | None) -> dict:
    """The ``perception`` section from JSON text, validated, defaults filled in."""
    return config_option(text, SCHEMA)


def _parser(prog: str, doc: str) -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog=f"signsplat {prog}", description=doc)
    p.add_argument("--config-json", default=None, help="the perception config section (JSON)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument("--detectors", choices=DETECTORS, default="shipped",
                   help="the shipped models (models/) or the pretrained real-world ones "
                        "(perception.pretrained; `signsplat models fetch`)")
    add_runtime_args(p)
    return p


def segment(argv: list[str]) -> int:
    """Masks for every frame of a frames table."""
    p = _parser("segment", segment.__doc__)
    p.add_argument("--frames", required=True, help="frames.parquet")
    p.add_argument("--out-dir", required=True, help="folder for masks/ and masks.parquet")
    p.add_argument("--timings", default=None, help="write a timings table here")
    a = p.parse_args(argv)
    cfg = perception_config(a.config_json)
    seg, kp = detector_specs(cfg, a.detectors, a.device)
    threads = a.threads
    from signsplat.perception.stages import segment_sequence, timings_table

    signer = None
    if a.detectors == "pretrained":
        from signsplat.perception.pretrained.select import SignerMasking, SignerRule

        signer = SignerMasking(kp, SignerRule.from_config(cfg["signer"]), threads)
    report = segment_sequence(a.frames, a.out_dir, seg, threads, cfg["skip_bad_frames"],
                              progress=not a.quiet, signer=signer)
    if a.timings:
        scene = str(report.table["scene"].iloc[0]) if len(report.table) else ""
        write_table(timings_table(report, scene, "segment"), a.timings, "timings")
    print(f"segment: {report.frames} frames, {report.timings['total']:.1f}s "
          f"({report.frames / max(report.timings['model'], 1e-9):.1f} frames/s in the model)")
    return 0


def detect_keypoints(argv: list[str]) -> int:
    """COCO-WholeBody keypoints for every frame, person box from the mask."""
    p = _parser("detect-keypoints", detect_keypoints.__doc__)
    p.add_argument("--frames", required=True, help="frames.parquet")
    p.add_argument("--masks", required=True, help="masks.parquet written by segment")
    p.add_argument("--persons", default=None,
                   help="persons.parquet written by segment: the pretrained keypointer takes "
                        "the signer chosen there")
    p.add_argument("--out", required=True, help="keypoints.parquet to write")
    p.add_argument("--timings", default=None, help="write a timings table here")
    a = p.parse_args(argv)
    cfg = perception_config(a.config_json)
    _, kp = detector_specs(cfg, a.detectors, a.device)
    threads = a.threads
    from signsplat.perception.stages import detect_sequence, timings_table

    report = detect_sequence(a.frames, a.masks, a.out, kp, threads, cfg["skip_bad_frames"],
                             progress=not a.quiet, min_area=cfg["keypoints"]["min_area"],
                             persons_path=a.persons if a.detectors == "pretrained" else None)
    if a.timings:
        scene = str(report.table["scene"].iloc[0]) if len(report.table) else ""
        write_table(timings_table(report, scene, "detect_keypoints"), a.timings, "timings")
    print(f"detect-keypoints: {report.frames} frames, {report.timings['total']:.1f}s")
    return 0


def perception_eval(argv: list[str]) -> int:
    """Accuracy against the simulator's ground truth and speed; prints the table."""
    p = _parser("perception-eval", perception_eval.__doc__)
    p.add_argument("--sim-dir", required=True, help="folder with frames/keypoints_gt.parquet")
    p.add_argument("--perception-dir", required=True, help="folder with masks/keypoints")
    p.add_argument("--out", required=True, help="eval.parquet to write")
    p.add_argument("--timings", nargs="*", default=[], help="part=timings.parquet ...")
    a = p.parse_args(argv)
    cfg = perception_config(a.config_json)
    seg, kp = detector_specs(cfg, a.detectors, a.device)
    from signsplat.perception.evaluate import evaluate_scene, format_table

    timing_paths = dict(t.split("=", 1) for t in a.timings)
    df = evaluate_scene(a.sim_dir, a.perception_dir, a.out, seg, kp,
                        a.threads, cfg["eval"]["speed_frames"], timing_paths)
    print(format_table(df))
    return 0


def perception_quality(argv: list[str]) -> int:
    """Detection rates and keypoint jitter of footage (no ground truth), and overlays."""
    p = _parser("perception-quality", perception_quality.__doc__)
    p.add_argument("--frames", required=True, help="frames.parquet")
    p.add_argument("--masks", required=True, help="masks.parquet")
    p.add_argument("--keypoints", required=True, help="keypoints.parquet")
    p.add_argument("--out", required=True, help="quality.parquet to write")
    p.add_argument("--overlays", default=None, help="folder for overlay PNGs")
    a = p.parse_args(argv)
    cfg = perception_config(a.config_json)["quality"]
    from signsplat.perception.quality import footage_quality, write_overlays

    df = footage_quality(a.frames, a.keypoints, a.out, cfg["min_score"])
    if a.overlays:
        write_overlays(a.frames, a.masks, a.keypoints, a.overlays, cfg["overlays"],
                       cfg["min_score"])
    from signsplat.perception.evaluate import format_table

    print(format_table(df))
    return 0


def train_detectors(argv: list[str]) -> int:
    """Train both default detectors side by side on simulated scenes, export ONNX."""
    p = _parser("train-detectors", train_detectors.__doc__)
    p.add_argument("--work", required=True, help="folder for logs and validation outputs")
    p.add_argument("--out-dir", required=True, help="folder for segmenter.onnx, keypoints.onnx")
    p.add_argument("--sim-dirs", nargs="+", required=True,
                   help="simulated scene folders (signsplat simulate-training-set writes "
                        "them); the last train.val_scenes are held out")
    p.add_argument("--which", choices=["both", "segmenter", "keypoints"], default="both")
    p.add_argument("--resume-keypoints", default=None,
                   help="keypoint state dict saved after a phase (keypoints.onnx.1.pt, .2.pt) "
                        "to go on from; the result equals an uninterrupted run's")
    p.add_argument("--resume-phase", type=int, choices=[1, 2], default=None,
                   help="the phase --resume-keypoints was saved after (default: from its "
                        "name, .1.pt or .2.pt)")
    p.add_argument("--adapt-from", default=None, metavar="KEYPOINTS_ONNX",
                   help="go on training this exported keypoint model on the scenes "
                        "(perception.train.kp_adapt_*) instead of training from scratch; "
                        "the held-out check uses the segmenter in --out-dir, else the shipped")
    a = p.parse_args(argv)
    if a.adapt_from and (a.which != "keypoints" or a.resume_keypoints):
        p.error("--adapt-from trains the keypoint model only: give --which keypoints and no "
                "--resume-keypoints")
    if a.adapt_from and not Path(a.adapt_from).is_file():
        p.error(f"--adapt-from: no file {a.adapt_from}")
    resume = {}
    if a.resume_keypoints:
        phase = a.resume_phase
        if phase is None:
            suffix = Path(a.resume_keypoints).name.rsplit(".", 2)[-2:]
            if suffix[-1] != "pt" or suffix[0] not in ("1", "2"):
                p.error(f"--resume-phase is needed: {a.resume_keypoints} is not named "
                        "*.1.pt or *.2.pt")
            phase = int(suffix[0])
        if not Path(a.resume_keypoints).is_file():
            p.error(f"--resume-keypoints: no file {a.resume_keypoints}")
        resume = {"resume": a.resume_keypoints, "resume_phase": phase}
    cfg = perception_config(a.config_json)
    from signsplat.perception.train import TrainConfig, TrainJob, run_job

    tcfg = TrainConfig.from_dict(cfg["train"])
    work, out_dir = Path(a.work), Path(a.out_dir)
    threads = a.threads
    sim_dirs = [str(d) for d in a.sim_dirs]
    missing = [d for d in sim_dirs if not (Path(d) / "frames.parquet").is_file()]
    if missing:
        p.error(f"--sim-dirs: no frames.parquet in {', '.join(missing)}")
    n_val = min(tcfg.val_scenes, len(sim_dirs) - 1)
    train_dirs = sim_dirs[:len(sim_dirs) - n_val]
    jobs = []
    if a.which in ("both", "segmenter"):
        jobs.append(TrainJob("segmenter", train_dirs, tcfg, str(out_dir / "segmenter.onnx"),
                             str(work / "logs" / "segmenter.log")))
    if a.adapt_from:
        jobs.append(TrainJob("adapt", train_dirs, tcfg, str(out_dir / "keypoints.onnx"),
                             str(work / "logs" / "keypoints.log"), {"init": a.adapt_from}))
    elif a.which in ("both", "keypoints"):
        jobs.append(TrainJob("keypoints", train_dirs, tcfg, str(out_dir / "keypoints.onnx"),
                             str(work / "logs" / "keypoints.log"), resume))
    workers = max(1, min(len(jobs), threads))
    if workers == 1:
        summaries = [run_job(job) for job in jobs]
    else:  # one process per model, each with its own torch threads
        with ProcessPoolExecutor(workers, mp_context=get_context("spawn")) as pool:
            summaries = list(pool.map(run_job, jobs))
    val = validate_on_held_out(sim_dirs[len(train_dirs):], out_dir, work / "val", cfg, threads)
    card = {"train_scenes": len(train_dirs),
            "validation_scenes": [Path(d).parent.name for d in sim_dirs[len(train_dirs):]],
            "validation": val, "models": summaries}
    from signsplat.io.atomic import write_bytes_atomic

    write_bytes_atomic(out_dir / "training.json", json.dumps(card, indent=2).encode())
    print(json.dumps(card, indent=2))
    return 0


def validate_on_held_out(sim_dirs: list[str], model_dir: Path, work: Path, cfg: dict,
                         threads: int) -> list[dict]:
    """Run both stages with the new models on held-out training scenes; accuracy rows."""
    import dataclasses

    from signsplat.perception.evaluate import accuracy
    from signsplat.perception.stages import detect_sequence, segment_sequence

    seg, kp = specs(cfg)
    if (model_dir / "segmenter.onnx").exists():  # else the configured one (--adapt-from)
        seg = dataclasses.replace(seg, path=str(model_dir / "segmenter.onnx"))
    kp = dataclasses.replace(kp, path=str(model_dir / "keypoints.onnx"), input_size=None)
    rows = []
    for d in sim_dirs:
        if not Path(seg.path).exists() or not Path(kp.path).exists():
            break
        out = work / Path(d).parent.name
        segment_sequence(Path(d) / "frames.parquet", out, seg, threads, progress=False)
        detect_sequence(Path(d) / "frames.parquet", out / "masks.parquet",
                        out / "keypoints.parquet", kp, threads, progress=False)
        rows += accuracy(d, out).to_dict("records")
    return rows
