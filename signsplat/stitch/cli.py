"""``signsplat sign "SENTENCE" ...``: English text -> gloss plan -> stitched SMPL-X track.

Writes, in ``--out``: ``{id}.plan.txt`` (the gloss sequence and why, with the coverage line),
``{id}.plan.json`` and ``{id}.smplx.parquet`` (table ``smplx_params`` with per-frame ``label``,
streamed). Rendering the track with the trained avatar is a later stage (issue 7).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import re
import time
from pathlib import Path

from signsplat.config import REPO_ROOT, validate
from signsplat.errors import InputError
from signsplat.io.atomic import write_bytes_atomic


def _slug(sentence: str) -> str:
    words = re.findall(r"[a-z0-9]+", sentence.lower())[:6]
    digest = hashlib.sha1(sentence.encode()).hexdigest()[:8]
    return "-".join(words + [digest]) if words else digest


def load_libraries(paths: list[str], body: str | None = None) -> dict:
    """Load and merge gloss libraries (later paths win), converted to 'flat' hands."""
    from signsplat.stitch.library import hands_mean, merge_libraries
    from signsplat.synth.glosses import load_gloss_library

    libs = [load_gloss_library(p) for p in paths]
    means = hands_mean(body) if body else None
    try:
        return merge_libraries(*libs, means=means)
    except ValueError as exc:
        raise InputError(f"{exc}; pass --body with the body model whose hands_meanl/r apply") \
            from None


def sign(argv: list[str]) -> int:
    """``signsplat sign "SENTENCE" --library PARQUET [--library ...] --out DIR``."""
    parser = argparse.ArgumentParser(prog="signsplat sign",
                                     description="English sentence -> stitched sign motion.")
    parser.add_argument("sentence", help="English text to sign")
    parser.add_argument("--library", action="append", required=True,
                        help="gloss library Parquet (repeat to merge; later ones win)")
    parser.add_argument("--out", required=True, help="output folder (results/stitched)")
    parser.add_argument("--id", default=None, help="output name (default: from the sentence)")
    parser.add_argument("--config-json", default="{}", help="the stitch config section as JSON")
    parser.add_argument("--body", default=None,
                        help="body model .npz (MANO hand mean for 'mano' libraries)")
    args = parser.parse_args(argv)

    from signsplat.stitch.motion import StitchConfig, stitch_frames, write_stitched_table
    from signsplat.stitch.text import load_pipeline, load_rules, sentence_to_glosses

    try:
        cfg = json.loads(args.config_json)
    except json.JSONDecodeError as exc:
        raise InputError(f"--config-json: not valid JSON ({exc})") from None
    cfg = validate(cfg, "stages/stitch.schema.yaml", "--config-json")
    rules_path = Path(cfg["rules"])
    rules = load_rules(rules_path if rules_path.is_absolute() else REPO_ROOT / rules_path)
    library = load_libraries(list(args.library) + list(cfg["libraries"]), args.body)
    t0 = time.perf_counter()
    plan = sentence_to_glosses(args.sentence, library, rules,
                               nlp=load_pipeline(cfg["spacy_pipeline"]))
    clips = [library[g] for g in plan.glosses]
    fps = {c.fps for c in clips}
    if len(fps) > 1:
        raise InputError(f"the glosses of this sentence have different frame rates {sorted(fps)}")
    out = Path(args.out)
    name = args.id or _slug(args.sentence)
    write_bytes_atomic(out / f"{name}.plan.txt", (plan.explain() + "\n").encode())
    write_bytes_atomic(out / f"{name}.plan.json", plan.to_json().encode())
    config = StitchConfig.from_dict(cfg)
    n = write_stitched_table(stitch_frames(clips, config), out / f"{name}.smplx.parquet",
                             scene=name, metadata={"fps": str(fps.pop() if fps else ""),
                                                   "sentence": args.sentence})
    print(" ".join(plan.glosses) or "(no glosses)")
    print(plan.coverage_line())
    print(f"wrote {n} frames to {out / (name + '.smplx.parquet')} "
          f"in {time.perf_counter() - t0:.2f} s (video rendering: avatar stage, not yet)")
    return 0
