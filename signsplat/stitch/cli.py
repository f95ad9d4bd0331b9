"""``signsplat sign "SENTENCE" [...]``: English text -> gloss plan -> stitched motion -> video.

Writes, in ``--out``, per sentence: ``{id}.plan.txt`` (the gloss sequence and why, with the
coverage line), ``{id}.plan.json`` and ``{id}.smplx.parquet`` (table ``smplx_params`` with
per-frame ``label``, streamed). With ``--avatar CHECKPOINT --body NPZ`` also ``{id}.mp4`` (the
avatar signing, rendered frame by frame into the video), ``{id}.baseline2d.mp4`` (the 2D
keypoint-interpolation baseline as a skeleton; ``--no-baseline`` skips it) and, for all
sentences together, the ``stitch_eval`` table (``--eval``, default ``OUT/stitch_eval.parquet``).
"""

from __future__ import annotations

import argparse
import hashlib
import logging
import re
import time
from pathlib import Path

from signsplat.config import REPO_ROOT, config_option
from signsplat.errors import InputError
from signsplat.io.atomic import write_bytes_atomic


def sentence_id(sentence: str) -> str:
    """Output file stem of a sentence: its first six words and a hash of the whole text."""
    return _slug(sentence)


def _slug(sentence: str) -> str:
    words = re.findall(r"[a-z0-9]+", sentence.lower())[:6]
    digest = hashlib.sha1(sentence.encode()).hexdigest()[:8]
    return "-".join(words + [digest]) if words else digest


def load_libraries(paths: list[str], body: str | None = None) -> dict:
    """Load and merge gloss libraries (later paths win), converted to 'flat' hands."""
    from signsplat.motion.clips import load_gloss_library
    from signsplat.stitch.library import hands_mean, merge_libraries

    libs = [load_gloss_library(p) for p in paths]
    means = hands_mean(body) if body else None
    try:
        return merge_libraries(*libs, means=means)
    except ValueError as exc:
        raise InputError(f"{exc}; pass --body with the body model whose hands_meanl/r apply") \
            from None


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="signsplat sign",
                                     description="English sentence -> stitched sign motion "
                                                 "(and, with --avatar, a video).")
    parser.add_argument("sentence", nargs="+", help="English text to sign (one or more)")
    parser.add_argument("--library", action="append", required=True,
                        help="gloss library Parquet (repeat to merge; later ones win)")
    parser.add_argument("--out", required=True, help="output folder (results/stitched)")
    parser.add_argument("--id", action="append", default=None,
                        help="output name per sentence (default: from the sentence)")
    parser.add_argument("--config-json", default="{}", help="the stitch config section as JSON")
    parser.add_argument("--body", default=None,
                        help="body model .npz (the avatar's; MANO hand mean for 'mano' "
                             "libraries)")
    parser.add_argument("--avatar", default=None,
                        help="trained avatar checkpoint.pt: render {id}.mp4 (needs --body)")
    parser.add_argument("--cameras", default=None,
                        help="cameras table of the avatar's scene (for the 'camera' choice)")
    parser.add_argument("--camera", default=None,
                        help="'front' or a view index (overrides the config's camera)")
    parser.add_argument("--no-baseline", action="store_true", help="skip the 2D baseline video")
    parser.add_argument("--eval", default=None,
                        help="stitch_eval table path (default OUT/stitch_eval.parquet)")
    from signsplat.device import add_runtime_args

    add_runtime_args(parser)
    return parser


def sign(argv: list[str]) -> int:
    """``signsplat sign "SENTENCE" ... --library PARQUET [--library ...] --out DIR
    [--avatar CKPT --body NPZ [--cameras CAMERAS]]``."""
    args = _parser().parse_args(argv)

    from signsplat.motion.stitching import (
        StitchConfig,
        stitch_frames,
        write_stitched_table,
    )
    from signsplat.stitch.text import load_pipeline, load_rules, sentence_to_glosses

    cfg = config_option(args.config_json, "stages/stitch.schema.yaml")
    if args.id is not None and len(args.id) != len(args.sentence):
        raise InputError(f"{len(args.id)} --id for {len(args.sentence)} sentence(s)")
    if args.avatar and not args.body:
        raise InputError("--avatar needs --body (the body model the avatar was trained on)")
    rules_path = Path(cfg["rules"])
    rules = load_rules(rules_path if rules_path.is_absolute() else REPO_ROOT / rules_path)
    library = load_libraries(list(args.library) + list(cfg["libraries"]), args.body)
    nlp = load_pipeline(cfg["spacy_pipeline"])
    config = StitchConfig.from_dict(cfg)
    out = Path(args.out)
    video = _VideoStage(args, cfg) if args.avatar else None
    evals = []
    for k, sentence in enumerate(args.sentence):
        t0 = time.perf_counter()
        plan = sentence_to_glosses(sentence, library, rules, nlp=nlp)
        clips = [library[g] for g in plan.glosses]
        fps = {c.fps for c in clips}
        if len(fps) > 1:
            raise InputError(f"the glosses of {sentence!r} have different frame rates "
                             f"{sorted(fps)}")
        name = args.id[k] if args.id else _slug(sentence)
        write_bytes_atomic(out / f"{name}.plan.txt", (plan.explain() + "\n").encode())
        write_bytes_atomic(out / f"{name}.plan.json", plan.to_json().encode())
        rate = fps.pop() if fps else None
        n = write_stitched_table(stitch_frames(clips, config), out / f"{name}.smplx.parquet",
                                 scene=name, metadata={"fps": str(rate or ""),
                                                       "sentence": sentence})
        print(" ".join(plan.glosses) or "(no glosses)")
        print(plan.coverage_line())
        print(f"wrote {n} frames to {out / (name + '.smplx.parquet')} "
              f"in {time.perf_counter() - t0:.2f} s")
        if video is not None:
            if not clips:
                raise InputError(f"{sentence!r}: no word could be signed or fingerspelled "
                                 f"({plan.coverage_line()}); nothing to render (plan written "
                                 f"to {out / (name + '.plan.txt')})")
            evals.append(video.run(clips, config, rate, out, name, sentence))
    if video is not None:
        from signsplat.stitch.evaluate import summary_lines, write_stitch_eval

        path = Path(args.eval) if args.eval else out / "stitch_eval.parquet"
        write_stitch_eval(evals, path)
        for line in summary_lines(__import__("pandas").concat(evals, ignore_index=True)):
            print(line)
        print(f"wrote {path}")
    return 0


class _VideoStage:
    """Renderer, camera and baseline tools loaded once for all sentences of a run."""

    def __init__(self, args, cfg: dict):
        from signsplat.body.keypoints import WholeBodyRegressor
        from signsplat.body.model import BodyModel
        from signsplat.device import use_runtime
        from signsplat.stitch.animate import (
            AvatarRenderer,
            choose_camera,
            upper_body_points,
        )

        logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
        device = use_runtime(args)
        body = BodyModel.from_file(args.body).to(device)
        background = cfg.get("background")
        self.renderer = AvatarRenderer.from_checkpoint(
            args.avatar, body, None, placement=cfg["placement"], background=background,
            device=device)
        choice = args.camera if args.camera is not None else cfg["camera"]
        rest = upper_body_points(body, self.renderer.identity) if args.cameras is None \
            else None
        self.camera = choose_camera(choice, cfg["size"] or None, args.cameras, rest)
        self.renderer.set_camera(self.camera)
        self.body = body
        self.regressor = WholeBodyRegressor(body).to(device)
        self.cfg = cfg
        self.baseline = not args.no_baseline
        self.batch = int(cfg["render_batch"])

    def run(self, clips, config, rate, out: Path, name: str, sentence: str):
        """Render one sentence's videos; returns its ``stitch_eval`` rows (no autograd inside;
        the caller's grad mode is left as it was)."""
        import torch

        with torch.no_grad():
            return self._run(clips, config, rate, out, name, sentence)

    def _run(self, clips, config, rate, out: Path, name: str, sentence: str):
        from signsplat.io.video import VideoWriter
        from signsplat.motion.stitching import stitch_clips, stitch_frames
        from signsplat.stitch.animate import render_track
        from signsplat.stitch.baseline2d import METRIC_BONES, render_baseline
        from signsplat.stitch.evaluate import BoneStats, StitchObserver, sentence_eval

        fps = float(self.cfg["fps"] or rate or 25.0)
        observer = StitchObserver(self.regressor, self.camera)
        with VideoWriter(out / f"{name}.mp4", fps) as writer:
            stats = render_track(stitch_frames(clips, config), self.renderer, writer,
                                 self.batch, observer)
        print(f"wrote {out / (name + '.mp4')}: {stats.frames} frames "
              f"{self.camera.width}x{self.camera.height}, {stats.render_fps:.1f} frames/s "
              f"rendering ({stats.cpu_ms_per_frame:.0f} ms CPU per frame)")
        bones_2d, base = None, None
        if self.baseline:
            bones_2d = BoneStats(METRIC_BONES)
            with VideoWriter(out / f"{name}.baseline2d.mp4", fps) as writer:
                base = render_baseline(stitch_frames(clips, config), self.body, self.regressor,
                                       self.camera, writer, self.renderer.identity,
                                       ease=self.cfg["baseline_ease"],
                                       on_frame=lambda f, kp: bones_2d.add(kp))
        return sentence_eval(self.renderer.scene, name, stitch_clips(clips, config),
                             float(rate or fps), observer.bones_3d, observer.bones_projected,
                             bones_2d, stats, base, text=sentence,
                             bones_face=observer.bones_face)
