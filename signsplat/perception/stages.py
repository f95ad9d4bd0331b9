"""The perception stages over whole sequences: ``segment`` and ``detect_keypoints``.

Both read the ``frames`` table (image paths relative to its folder), work in batches with a
progress bar, write their outputs atomically and return their tables. A missing or corrupt
frame image does not stop the others: every readable frame's outputs are written, then an
:class:`~signsplat.errors.InputError` names the bad file(s) (or, with ``skip_bad_frames``,
a warning is printed and the bad frames are left out of the tables).
"""

from __future__ import annotations

import json
import os
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd
from tqdm import tqdm

from signsplat.body.joints import NUM_KEYPOINTS
from signsplat.errors import InputError
from signsplat.io.tables import read_table, write_table
from signsplat.perception.contracts import (KeypointSpec, SegmenterSpec, load_keypointer,
                                            load_segmenter)
from signsplat.io.images import read_rgb, write_mask
from signsplat.perception.keypoints import detect_batch
from signsplat.perception.segment import mask_stats, segment_batch
from signsplat.perception.tables import MASKS_TABLE, PERSONS_TABLE  # noqa: F401  (registers)



@dataclass
class StageReport:
    """What a stage did: its table, the frames it could not read and its timings (seconds)."""

    table: pd.DataFrame
    bad_frames: list[str] = field(default_factory=list)
    timings: dict[str, float] = field(default_factory=dict)
    frames: int = 0


def _batches(n: int, size: int):
    for start in range(0, n, max(1, size)):
        yield range(start, min(n, start + max(1, size)))


def _read_frames(rows: pd.DataFrame, base: Path) -> tuple[list, list[str]]:
    images, bad = [], []
    for rel in rows["image"]:
        try:
            images.append(read_rgb(base / rel))
        except InputError as exc:
            images.append(None)
            bad.append(str(exc))
    return images, bad


def _readable_batches(frames: pd.DataFrame, base: Path, size: int, bad: list[str],
                      timings: dict[str, float], desc: str, progress: bool):
    """``frames`` in batches of ``size``: ``(chunk, images, good)``, ``good`` the positions
    of the images that could be read (``None`` in ``images`` elsewhere). Unreadable frames go
    to ``bad``, the reading time to ``timings["read"]``; a progress bar ``desc`` on stderr."""
    with tqdm(total=len(frames), desc=desc, unit="frame", disable=not progress,
              file=sys.stderr) as bar:
        for idx in _batches(len(frames), size):
            chunk = frames.iloc[list(idx)]
            t0 = time.perf_counter()
            images, errs = _read_frames(chunk, base)
            timings["read"] += time.perf_counter() - t0
            bad += errs
            yield chunk, images, [i for i, im in enumerate(images) if im is not None]
            bar.update(len(chunk))


def _finish(report: StageReport, skip_bad: bool, stage: str) -> StageReport:
    if report.bad_frames:
        msg = (f"{len(report.bad_frames)} frame image(s) could not be read: "
               + "; ".join(report.bad_frames)
               + f" (outputs of the other {report.frames} frame(s) were written)")
        if not skip_bad:
            raise InputError(msg)
        print(f"{stage}: warning: {msg}", file=sys.stderr)
    return report


def timings_table(report: StageReport, scene: str, stage: str) -> pd.DataFrame:
    """The stage's timings as a ``timings`` table."""
    return pd.DataFrame({
        "scene": scene, "stage": stage, "step": list(report.timings),
        "seconds": np.array(list(report.timings.values()), np.float64),
        "count": np.int64(report.frames),
    })


def segment_sequence(frames_path: str | os.PathLike, out_dir: str | os.PathLike,
                     spec: SegmenterSpec, threads: int = 1, skip_bad_frames: bool = False,
                     progress: bool = True, signer=None) -> StageReport:
    """Masks for every row of a ``frames`` table.

    Writes ``out_dir/masks/{view:02d}/{frame:04d}.png`` (0/255), ``out_dir/masks.parquet``
    (table ``masks``), ``out_dir/persons.parquet`` (table ``persons``) and
    ``out_dir/masked_frames.parquet``: the input ``frames`` table with these masks in its
    ``mask`` column (paths relative to ``out_dir``), for stages that train on masked frames of
    footage, whose own frames table has no masks. ``signer``
    (:class:`~signsplat.perception.pretrained.select.SignerMasking`) chooses the signer among
    the people in each frame and restricts the mask to them; without it the persons table has
    no rows. When no frame has a person at all, the outputs are written and an
    :class:`~signsplat.errors.InputError` names the input and its frames. Returns the report
    (its table has one row per readable frame).
    """
    t_start = time.perf_counter()
    frames_path, out_dir = Path(frames_path), Path(out_dir)
    source = read_table(frames_path, "frames")
    frames = source.sort_values(["view", "frame"], kind="stable").reset_index(drop=True)
    model = load_segmenter(spec, threads)
    t = {"load": time.perf_counter() - t_start, "read": 0.0, "model": 0.0, "write": 0.0}
    rows, bad, people = [], [], []
    for chunk, images, good in _readable_batches(frames, frames_path.parent, spec.batch_size,
                                                 bad, t, "segment", progress):
        t1 = time.perf_counter()
        alphas = segment_batch(model, spec, [images[i] for i in good]) if good else []
        t2 = time.perf_counter()
        for i, alpha in zip(good, alphas, strict=True):
            r = chunk.iloc[i]
            if signer is not None:
                alpha, found = signer(images[i], alpha, int(r["view"]))
                people += [dict(scene=r["scene"], view=int(r["view"]), frame=int(r["frame"]),
                                **p) for p in found]
            st = mask_stats(alpha, spec.threshold)
            rel = f"masks/{int(r['view']):02d}/{int(r['frame']):04d}.png"
            write_mask(out_dir / rel, st["mask"])
            rows.append((r["scene"], int(r["view"]), int(r["frame"]), rel, st["area"],
                         *st["box"], st["confidence"]))
        t3 = time.perf_counter()
        t["model"] += t2 - t1
        t["write"] += t3 - t2
    df = pd.DataFrame(rows, columns=["scene", "view", "frame", "mask", "area", "x0", "y0", "x1",
                                     "y1", "confidence"])
    df = df.astype({"view": "int32", "frame": "int32", "area": "int64", "x0": "float32",
                    "y0": "float32", "x1": "float32", "y1": "float32",
                    "confidence": "float32"})
    write_table(df, out_dir / "masks.parquet", "masks", metadata={"model": str(spec.path)})
    write_table(persons_frame(people), out_dir / "persons.parquet", "persons",
                metadata={"rule": json.dumps(signer.rule.__dict__) if signer else ""})
    masked = frames.merge(df[["view", "frame", "mask"]], on=["view", "frame"],
                          suffixes=("_input", ""))
    masked["image"] = [os.path.relpath(frames_path.parent / p, out_dir) for p in masked["image"]]
    write_table(masked[list(source.columns)], out_dir / "masked_frames.parquet", "frames",
                metadata=source.attrs)
    t["total"] = time.perf_counter() - t_start
    report = StageReport(df, bad, t, len(df))
    if len(df) and not (df["area"] > 0).any():
        raise InputError(f"{frames_source(frames_path)}: no person found in any of its "
                         f"{len(df)} frame(s) (frames {df['frame'].min()}-{df['frame'].max()};"
                         f" masks in {out_dir})")
    return _finish(report, skip_bad_frames, "segment")


def frames_source(frames_path: str | os.PathLike) -> str:
    """What a frames table was made from, for messages: the camera files ingest recorded
    (``cameras`` metadata), else the table itself."""
    meta = read_table(frames_path, "frames").attrs
    cams = meta.get("cameras")
    return "; ".join(json.loads(cams)) if cams else str(frames_path)


def persons_frame(rows: list[dict]) -> pd.DataFrame:
    """The ``persons`` table from per-person dicts (scene, view, frame + PERSON_COLUMNS)."""
    from signsplat.perception.pretrained.select import PERSON_COLUMNS

    cols = ["scene", "view", "frame", *PERSON_COLUMNS]
    df = pd.DataFrame(rows, columns=cols)
    f32 = {c: "float32" for c in cols[5:-2]}
    return df.astype({"view": "int32", "frame": "int32", "person": "int16", "score": "float32",
                      **f32, "chosen": "bool", "chosen_by": "str"})


class SimccKeypointer:
    """A top-down SimCC model (RTMPose/RTMW contract): one batched call per chunk of frames."""

    source = "onnx"

    def __init__(self, spec: KeypointSpec, threads: int = 1):
        self.spec = spec
        self.model = load_keypointer(spec, threads)
        self.path, self.batch_size, self.min_area = str(spec.path), spec.batch_size, spec.min_area
        self.num_keypoints = spec.num_keypoints

    def detect(self, images: list, boxes: list, views: list[int], persons=None):
        """(N, 133, 2) pixels and (N, 133) scores for frames in time order per view (the
        person box is the mask's; ``persons`` is not used)."""
        return detect_batch(self.model, self.spec, images, boxes)

    def finish(self, frames, xy, sc):
        """One view's keypoints after its last frame: unchanged (frames are independent)."""
        return xy, sc, {}

    def summary(self) -> str:
        """Nothing to add to the stage's log (the model's points are taken as they are)."""
        return ""


def open_keypointer(spec, threads: int = 1, min_area: int | None = None):
    """The keypointer for ``spec``: a :class:`KeypointSpec` (SimCC ONNX model) or a
    :class:`~signsplat.perception.pretrained.keypointer.MediaPipeSpec` (the pretrained
    whole-body keypointer) or a :class:`~signsplat.perception.hands.HandsSpec` (a SimCC
    model with MediaPipe's hands); ``min_area`` overrides the spec's (masks smaller = no
    person)."""
    from signsplat.perception.hands import HandsKeypointer, HandsSpec

    if isinstance(spec, HandsSpec):
        kp = HandsKeypointer(open_keypointer(spec.base, threads), spec, threads)
    elif isinstance(spec, KeypointSpec):
        kp = SimccKeypointer(spec, threads)
    else:
        from signsplat.perception.pretrained.keypointer import MediaPipeKeypointer

        kp = MediaPipeKeypointer(spec, threads)
    if min_area is not None:
        kp.min_area = int(min_area)
    return kp


def detect_sequence(frames_path: str | os.PathLike, masks_path: str | os.PathLike,
                    out_path: str | os.PathLike, spec, threads: int = 1,
                    skip_bad_frames: bool = False, progress: bool = True,
                    min_area: int | None = None,
                    persons_path: str | os.PathLike | None = None) -> StageReport:
    """COCO-WholeBody keypoints for every frame that has a row in the ``masks`` table.

    ``spec`` chooses the keypointer (:func:`open_keypointer`). A frame whose mask is empty
    (fewer than ``min_area`` pixels) gets score 0 and NaN x, y; the SimCC models take the
    mask's box as the person box, the pretrained keypointer the signer the segment stage
    chose, and where the others stood (``persons_path``, table ``persons``) when given.
    Writes ``out_path`` (table ``keypoints``, one row per keypoint, scores in [0, 1]).
    """
    t_start = time.perf_counter()
    frames_path = Path(frames_path)
    frames = read_table(frames_path, "frames")
    masks = read_table(masks_path, "masks")
    frames = frames.merge(masks[["view", "frame", "area", "x0", "y0", "x1", "y1"]],
                          on=["view", "frame"], how="left", indicator=True)
    frames = frames.sort_values(["view", "frame"], kind="stable").reset_index(drop=True)
    bad = [f"{frames_path.parent / r['image']}: no row in {masks_path}"
           for _, r in frames[frames["_merge"] != "both"].iterrows()]
    frames = frames[frames["_merge"] == "both"].reset_index(drop=True)
    kp = open_keypointer(spec, threads, min_area)
    k = kp.num_keypoints
    chosen = {}  # (view, frame) -> the signer's (hip, size point), then the others'
    if persons_path is not None:
        ppl = read_table(persons_path, "persons")
        for (view, frame), g in ppl.groupby(["view", "frame"]):
            if g["chosen"].any():
                g = g.sort_values("chosen", ascending=False, kind="stable")
                chosen[(int(view), int(frame))] = g[["hip_x", "hip_y", "scale_x", "scale_y"]
                                                    ].to_numpy(np.float64).reshape(-1, 2, 2)
    t = {"load": time.perf_counter() - t_start, "read": 0.0, "model": 0.0, "write": 0.0}
    keys, xys, scs = [], [], []
    for chunk, images, good in _readable_batches(frames, frames_path.parent, kp.batch_size,
                                                 bad, t, "keypoints", progress):
        t1 = time.perf_counter()
        boxes = []
        for i in good:
            b = chunk.iloc[i][["x0", "y0", "x1", "y1"]].to_numpy(np.float64)
            small = chunk.iloc[i]["area"] < kp.min_area
            boxes.append(None if small or not np.all(np.isfinite(b)) or b[2] <= b[0]
                         or b[3] <= b[1] else b)
        if good:
            keys_good = [(int(chunk.iloc[i]["view"]), int(chunk.iloc[i]["frame"])) for i in good]
            people = [chosen.get(key) for key in keys_good] if persons_path is not None else None
            xy, sc = kp.detect([images[i] for i in good], boxes, [v for v, _ in keys_good],
                               people)
            for j, i in enumerate(good):
                r = chunk.iloc[i]
                keys.append((r["scene"], int(r["view"]), int(r["frame"])))
                xys.append(xy[j])
                scs.append(sc[j])
        t["model"] += time.perf_counter() - t1
    t0 = time.perf_counter()
    xys, scs = _finish_views(kp, keys, xys, scs)
    t["model"] += time.perf_counter() - t0
    note = kp.summary()
    if note:
        print(f"keypoints: {note}", file=sys.stderr)
    t0 = time.perf_counter()
    df = keypoints_frame(keys, xys, scs, k)
    write_table(df, out_path, "keypoints",
                metadata={"model": kp.path, "source": kp.source, "note": note})
    t["write"] += time.perf_counter() - t0
    t["total"] = time.perf_counter() - t_start
    report = StageReport(df, bad, t, len(keys))
    return _finish(report, skip_bad_frames, "detect_keypoints")


def _finish_views(kp, keys: list[tuple[str, int, int]], xys: list, scs: list
                  ) -> tuple[list, list]:
    """Each view's keypoints through the keypointer's ``finish`` (what needs the whole view,
    e.g. clearing a neighbour's still hand); logs what was cleared."""
    xys, scs = list(xys), list(scs)
    by_view: dict[tuple[str, int], list[int]] = {}
    for i, (scene, view, _) in enumerate(keys):
        by_view.setdefault((scene, view), []).append(i)
    for (scene, view), rows in by_view.items():
        rows = sorted(rows, key=lambda i: keys[i][2])
        frames = np.array([keys[i][2] for i in rows])
        xy, sc, cleared = kp.finish(frames, np.stack([xys[i] for i in rows]),
                                    np.stack([scs[i] for i in rows]))
        for j, i in enumerate(rows):
            xys[i], scs[i] = xy[j], sc[j]
        for side, n in cleared.items():
            if n:
                print(f"keypoints: {scene} view {view}: the {side} hand cleared in {n} frame(s) "
                      f"(it stays put while the pose's wrist moves: another person's hand)",
                      file=sys.stderr)
    return xys, scs


def keypoints_frame(keys: list[tuple[str, int, int]], xys: list[np.ndarray],
                    scores: list[np.ndarray], k: int = NUM_KEYPOINTS) -> pd.DataFrame:
    """Long ``keypoints`` table from per-frame (K, 2) positions and (K,) scores."""
    n = len(keys)
    xy = np.stack(xys).reshape(n * k, 2) if n else np.zeros((0, 2), np.float32)
    sc = np.stack(scores).reshape(n * k) if n else np.zeros(0, np.float32)
    return pd.DataFrame({
        "scene": np.repeat([s for s, _, _ in keys], k).astype(object),
        "view": np.repeat([v for _, v, _ in keys], k).astype(np.int32),
        "frame": np.repeat([f for _, _, f in keys], k).astype(np.int32),
        "kp": np.tile(np.arange(k, dtype=np.int16), n),
        "x": xy[:, 0].astype(np.float32),
        "y": xy[:, 1].astype(np.float32),
        "score": sc.astype(np.float32),
    })
