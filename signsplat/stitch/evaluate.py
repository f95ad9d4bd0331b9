"""``stitch_eval``: figures of stitched videos (issue 7, paper 4.6).

Per sentence, one row per (method, join, metric):

- ``stitch_3d``, per join (``join`` >= 0): ``transition_frames``, ``peak_velocity_deg_s``,
  ``peak_jerk_deg_s3`` (:func:`signsplat.stitch.metrics.join_metrics`).
- ``stitch_3d``, whole video (``join`` = -1): bone-length variation of the posed body's
  skeleton (SMPL-X kinematic bones, joint to parent, 3D, metres) over the bones the pose
  alone sets (``bone_*``: zero up to float32 rounding) and over the neck/head/jaw/eye bones
  (``face_bone_*``: SMPL-X regresses those joints from vertices that the expression blend
  shapes move, so mouthing changes them slightly); ``frames``; ``render_fps`` (posing +
  rasterizing, wall clock), ``render_fps_encoded`` (with H.264 encoding) and
  ``render_cpu_ms_per_frame`` (process CPU time, all threads: comparable on a loaded
  machine).
- ``stitch_3d_projected``: bone-length variation of the 3D stitching's keypoints projected
  with the video's camera (the 2D skeleton a perfect 3D motion gives; foreshortening alone).
- ``baseline_2d``: bone-length variation of the 2D-stitched skeleton
  (:mod:`signsplat.stitch.baseline2d`), ``draw_fps``.

Bone-length variation, per bone over the frames of the video: ``bone_max_rel_range`` is the
largest ``(max - min) / mean`` over the bones, ``bone_mean_cv`` the mean over bones of
``std / mean``. 2D figures use :data:`~signsplat.stitch.baseline2d.METRIC_BONES` (torso,
arms, hands). Statistics are accumulated frame by frame (:class:`BoneStats`), so a long
video needs no per-frame storage.
"""

from __future__ import annotations

import os
from collections.abc import Sequence

import numpy as np
import pandas as pd

from signsplat.body import joints as JN
from signsplat.io.tables import Table, register_table, write_table
from signsplat.stitch.metrics import join_metrics

STITCH_EVAL = register_table(Table(
    "stitch_eval",
    "Stitched sign videos: per-join motion figures, bone-length variation of the 3D stitching "
    "and of the 2D baseline, render speed. One row per (sentence, method, join, metric).",
    {
        "scene": "str scene of the avatar",
        "sentence": "str sentence id (output file stem)",
        "method": "str stitch_3d | stitch_3d_projected | baseline_2d",
        "join": "int64 join index between glosses g and g+1; -1 for whole-video figures",
        "metric": "str transition_frames | peak_velocity_deg_s | peak_jerk_deg_s3 | "
                  "bone_max_rel_range | bone_mean_cv | face_bone_max_rel_range | "
                  "face_bone_mean_cv | frames | render_fps | render_fps_encoded | "
                  "render_cpu_ms_per_frame | draw_fps",
        "value": "float64 value in the unit",
        "unit": "str frames | deg/s | deg/s^3 | ratio | frames/s | ms",
    },
    extra_columns=True,  # from_gloss, to_gloss (str, per join), text (str, the sentence)
))

#: SMPL-X kinematic bones (parent joint, joint) for joints 1..54.
SMPLX_BONES = [(JN.SMPLX_PARENTS[j], j) for j in range(1, JN.NUM_JOINTS)]
#: Joints SMPL-X regresses from vertices that the expression blend shapes move (neck, head,
#: jaw, eyes): their bones change length with the facial expression (mouthing), not with pose.
EXPRESSION_JOINTS = tuple(JN.JOINT_INDEX[n] for n in ("neck", "head", "jaw", "left_eye",
                                                      "right_eye"))
#: Bones set by the pose alone (every other bone): their lengths must not vary.
POSE_BONES = [b for b in SMPLX_BONES if b[1] not in EXPRESSION_JOINTS]
FACE_BONES = [b for b in SMPLX_BONES if b[1] in EXPRESSION_JOINTS]


class BoneStats:
    """Running per-bone length statistics (min, max, mean, std) over frames.

    Args:
        bones: (N, 2) point index pairs.
    """

    def __init__(self, bones: Sequence[tuple[int, int]]):
        self.bones = np.asarray(bones, np.int64).reshape(-1, 2)
        n = len(self.bones)
        self.frames = 0
        self.lo = np.full(n, np.inf)
        self.hi = np.full(n, -np.inf)
        self.sum = np.zeros(n)
        self.sumsq = np.zeros(n)
        self._ref = None  # first frame's lengths: sums are of deviations from it (stable)

    def add(self, points: np.ndarray) -> None:
        """points (B, K, D) or (K, D) (D = 2 pixels or 3 metres) of one or more frames."""
        p = np.asarray(points, np.float64)
        if p.ndim == 2:
            p = p[None]
        length = np.linalg.norm(p[:, self.bones[:, 0]] - p[:, self.bones[:, 1]], axis=-1)
        if self._ref is None:
            self._ref = length[0].copy()
        d = length - self._ref
        self.lo = np.minimum(self.lo, length.min(0))
        self.hi = np.maximum(self.hi, length.max(0))
        self.sum += d.sum(0)
        self.sumsq += (d * d).sum(0)
        self.frames += len(length)

    def summary(self) -> dict[str, float]:
        """``bone_max_rel_range`` and ``bone_mean_cv`` (0 when there are no frames); bones of
        (near) zero mean length are skipped."""
        if self.frames == 0 or not len(self.bones):
            return {"bone_max_rel_range": 0.0, "bone_mean_cv": 0.0}
        mean_d = self.sum / self.frames
        mean = self._ref + mean_d
        var = np.maximum(self.sumsq / self.frames - mean_d ** 2, 0.0)
        ok = mean > 1e-9
        if not ok.any():
            return {"bone_max_rel_range": 0.0, "bone_mean_cv": 0.0}
        rel = (self.hi - self.lo)[ok] / mean[ok]
        cv = np.sqrt(var[ok]) / mean[ok]
        return {"bone_max_rel_range": float(rel.max()), "bone_mean_cv": float(cv.mean())}

    def per_bone(self) -> np.ndarray:
        """(N,) relative range ``(max - min) / mean`` of each bone."""
        mean = self._ref + self.sum / max(self.frames, 1)
        return (self.hi - self.lo) / np.maximum(mean, 1e-12)


class StitchObserver:
    """``on_batch`` callback of :func:`signsplat.stitch.animate.render_track`: accumulates the
    3D bone lengths of the posed joints and the 2D bone lengths of the projected keypoints."""

    def __init__(self, regressor=None, camera=None):
        from signsplat.stitch.baseline2d import METRIC_BONES

        self.bones_3d = BoneStats(POSE_BONES)
        self.bones_face = BoneStats(FACE_BONES)
        self.bones_projected = BoneStats(METRIC_BONES)
        self.regressor = regressor
        self.camera = camera

    def __call__(self, frames, out) -> None:
        joints = out.joints.detach().cpu().numpy()
        self.bones_3d.add(joints)
        self.bones_face.add(joints)
        if self.regressor is not None and self.camera is not None:
            kp = self.regressor(out).detach().cpu().numpy()
            self.bones_projected.add(self.camera.project(kp)[0])


def _rows(method: str, stats: BoneStats, prefix: str = "") -> list[dict]:
    return [dict(method=method, join=-1, metric=prefix + k, value=v, unit="ratio")
            for k, v in stats.summary().items()]


def sentence_eval(scene: str, sentence: str, track: dict, fps: float,
                  bones_3d: BoneStats | None = None, bones_projected: BoneStats | None = None,
                  bones_2d: BoneStats | None = None, render=None, baseline=None,
                  text: str = "", bones_face: BoneStats | None = None) -> pd.DataFrame:
    """The ``stitch_eval`` rows of one sentence.

    Args:
        track: :func:`~signsplat.motion.stitching.stitch_clips` output of the sentence.
        fps: frame rate of the track.
        bones_3d / bones_projected / bones_2d: :class:`BoneStats` of the 3D skeleton
            (:data:`POSE_BONES`), of its projection and of the 2D baseline (None: not
            measured); bones_face: of :data:`FACE_BONES`.
        render / baseline: :class:`~signsplat.stitch.animate.RenderStats` of the avatar video
            and of the baseline drawing (None: not made).
    """
    rows = []
    for r in join_metrics(track, fps).itertuples(index=False):
        common = dict(method="stitch_3d", join=int(r.join), from_gloss=r.from_gloss,
                      to_gloss=r.to_gloss)
        rows += [dict(common, metric="transition_frames", value=float(r.transition_frames),
                      unit="frames"),
                 dict(common, metric="peak_velocity_deg_s", value=r.peak_velocity_deg_s,
                      unit="deg/s"),
                 dict(common, metric="peak_jerk_deg_s3", value=r.peak_jerk_deg_s3,
                      unit="deg/s^3")]
    n = len(track.get("label", []))
    rows.append(dict(method="stitch_3d", join=-1, metric="frames", value=float(n),
                     unit="frames"))
    if bones_3d is not None:
        rows += _rows("stitch_3d", bones_3d)
    if bones_face is not None:
        rows += _rows("stitch_3d", bones_face, "face_")
    if bones_projected is not None:
        rows += _rows("stitch_3d_projected", bones_projected)
    if bones_2d is not None:
        rows += _rows("baseline_2d", bones_2d)
    if render is not None:
        rows += [dict(method="stitch_3d", join=-1, metric="render_fps", value=render.render_fps,
                      unit="frames/s"),
                 dict(method="stitch_3d", join=-1, metric="render_fps_encoded",
                      value=render.total_fps, unit="frames/s"),
                 dict(method="stitch_3d", join=-1, metric="render_cpu_ms_per_frame",
                      value=render.cpu_ms_per_frame, unit="ms")]
    if baseline is not None:
        rows.append(dict(method="baseline_2d", join=-1, metric="draw_fps",
                         value=baseline.total_fps, unit="frames/s"))
    df = pd.DataFrame(rows, columns=["method", "join", "metric", "value", "unit", "from_gloss",
                                     "to_gloss"])
    df.insert(0, "sentence", sentence)
    df.insert(0, "scene", scene)
    df["join"] = df["join"].astype("int64")
    df["value"] = df["value"].astype("float64")
    for col in ("from_gloss", "to_gloss"):
        df[col] = df[col].astype(object).where(df[col].notna(), "").astype(str)
    df["text"] = text
    return df


def write_stitch_eval(frames: Sequence[pd.DataFrame], path: str | os.PathLike) -> os.PathLike:
    """Concatenate sentences' rows and write the ``stitch_eval`` table atomically."""
    cols = list(STITCH_EVAL.columns) + ["from_gloss", "to_gloss", "text"]
    df = pd.concat(list(frames), ignore_index=True) if frames else pd.DataFrame(columns=cols)
    return write_table(df, path, "stitch_eval")


def summary_lines(df: pd.DataFrame) -> list[str]:
    """Short human-readable figures of a ``stitch_eval`` table (for logs and the CLI)."""
    lines = []
    for sent, d in df.groupby("sentence", sort=False):
        j = d[d["join"] >= 0]
        whole = d[d["join"] < 0].set_index(["method", "metric"])["value"]

        def get(method, metric):
            return whole.get((method, metric), float("nan"))

        tf = j[j.metric == "transition_frames"].value
        pv = j[j.metric == "peak_velocity_deg_s"].value
        lines.append(
            f"{sent}: {int(get('stitch_3d', 'frames'))} frames, {len(tf)} joins"
            + (f" (transition {int(tf.min())}-{int(tf.max())} frames, median {tf.median():g};"
               f" peak {pv.max():.0f} deg/s)" if len(tf) else "")
            + f"; bone length max rel. range 3D {get('stitch_3d', 'bone_max_rel_range'):.2e},"
            f" 3D projected {get('stitch_3d_projected', 'bone_max_rel_range'):.3f},"
            f" 2D baseline {get('baseline_2d', 'bone_max_rel_range'):.3f};"
            f" render {get('stitch_3d', 'render_fps'):.1f} frames/s"
            f" ({get('stitch_3d', 'render_cpu_ms_per_frame'):.0f} ms CPU/frame)")
    return lines
