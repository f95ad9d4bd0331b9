"""The COLMAP comparison table: COLMAP runs on a scene's images vs the SMPL-X camera solve.

Runs (paper 3.1: COLMAP struggles on static sparse rigs, hence the body-model anchor):
- ``colmap_static_frame_{k}``: the C views of time step k (one static sparse rig snapshot);
- ``colmap_sequence``: all views x an even subsample of frames;
- ``smplx_camera_solve``: the fitting stage's cameras (``cameras_fit.parquet``), when present.
each COLMAP run under every configured ``setting`` (by default: known intrinsics, estimated
intrinsics, and known intrinsics with relaxed mapper thresholds). Camera
errors are measured after a similarity alignment to the ground-truth cameras
(:mod:`signsplat.colmap.align`), the same way for every method.
"""

from __future__ import annotations

import logging
import os
import tempfile
from dataclasses import dataclass, fields
from pathlib import Path

import numpy as np
import pandas as pd

from signsplat.colmap.align import align_cameras
from signsplat.colmap.ply import write_points_ply
from signsplat.colmap.run import ColmapOptions, ColmapResult, ImageInput, run_colmap
from signsplat.errors import InputError
from signsplat.io.tables import Table, register_table

log = logging.getLogger(__name__)

COLMAP_COMPARE = register_table(Table(
    "colmap_compare",
    "COLMAP reconstructions vs the SMPL-X camera solve: one row per run.",
    {
        "scene": "str sequence name",
        "method": "str colmap_static_frame_{k} | colmap_sequence | smplx_camera_solve",
        "setting": "str name of the COLMAP setting (e.g. known_intrinsics, estimated_intrinsics, "
                   "known_intrinsics_relaxed); fit mode + keypoint source for the SMPL-X solve",
        "frame": "int32 time step of a static-rig run, -1 when the run spans all frames",
        "images": "int32 input images (views x frames)",
        "registered": "int32 images with a recovered pose (cameras for the SMPL-X solve)",
        "views_registered": "int32 distinct cameras (views) among the registered images",
        "points3d": "Int64 reconstructed 3D points (null for the SMPL-X solve)",
        "reproj_error_px": "float64 mean reprojection error in pixels (NaN when unknown)",
        "rot_error_deg": "float64 mean camera rotation error after similarity alignment, degrees",
        "rot_error_deg_max": "float64 worst camera rotation error, degrees",
        "centre_error_m": "float64 mean camera centre error after similarity alignment, metres",
        "centre_error_m_max": "float64 worst camera centre error, metres",
        "focal_error_pct": "float64 mean |f - f_gt| / f_gt in percent (NaN when fixed/unknown)",
        "alignment": "str umeyama | orientation (degenerate centres) | '' (nothing to align)",
        "seconds": "float64 wall-clock seconds of the run; features and matches it shares with "
                   "an earlier setting count as long as they took there (the run alone)",
        "cpu_seconds": "float64 CPU seconds of the run over all threads, counted the same way "
                       "(NaN when unknown)",
        "status": "str 'ok' or the reason of a failure (failed/error/crashed: ...)",
        "ply": "str PLY of the run's points in the world frame, relative to the table ('' none)",
    },
))

#: ColmapOptions fields a setting may override (the config's top-level values are the base).
MAPPER_KEYS = ("max_num_features", "min_num_matches", "init_min_num_inliers",
               "init_min_tri_angle", "abs_pose_min_num_inliers", "abs_pose_min_inlier_ratio",
               "min_model_size")


@dataclass(frozen=True)
class Setting:
    """A named way to run COLMAP: fixed or estimated intrinsics, and mapper threshold overrides."""

    name: str
    known_intrinsics: bool = True
    overrides: tuple[tuple[str, float], ...] = ()

    @classmethod
    def from_dict(cls, d: dict) -> "Setting":
        d = dict(d)
        name, known = str(d.pop("name")), bool(d.pop("known_intrinsics", True))
        bad = sorted(set(d) - set(MAPPER_KEYS))
        if bad:
            raise InputError(f"colmap setting {name!r}: unknown key(s) {bad}; "
                             f"allowed {list(MAPPER_KEYS)}")
        return cls(name, known, tuple(sorted(d.items())))


@dataclass(frozen=True)
class CompareConfig:
    """The `colmap` section of the workflow config; its schema (colmap.schema.yaml) documents
    every field and holds every default: build with :meth:`from_dict`."""

    static_frames: tuple[int, ...] | None
    num_static_frames: int
    sequence_frames: int
    settings: tuple[Setting, ...]
    mapper: dict  # the base SIFT and mapper thresholds, by MAPPER_KEYS name
    seed: int
    isolate: bool
    timeout_seconds: float
    max_runtime_seconds: float

    @classmethod
    def from_dict(cls, cfg: dict | None, source: str = "colmap config") -> "CompareConfig":
        """From a ``colmap`` section; missing keys get the schema's defaults."""
        from signsplat.config import validate

        cfg = validate(dict(cfg or {}), "stages/colmap.schema.yaml", source)
        if cfg.get("static_frames") is not None:
            cfg["static_frames"] = tuple(int(f) for f in cfg["static_frames"])
        cfg["settings"] = tuple(Setting.from_dict(d) for d in cfg["settings"])
        names = [st.name for st in cfg["settings"]]
        if len(set(names)) != len(names):
            raise InputError(f"{source}: setting names must be unique, got {names}")
        cfg["mapper"] = {k: cfg.pop(k) for k in MAPPER_KEYS}
        return cls(**cfg)

    def options(self, setting: Setting, threads: int) -> ColmapOptions:
        """The options of one run: the base thresholds, then the setting's overrides."""
        return ColmapOptions(
            known_intrinsics=setting.known_intrinsics, num_threads=threads, seed=self.seed,
            max_runtime_seconds=self.max_runtime_seconds, isolate=self.isolate,
            timeout_seconds=self.timeout_seconds, **{**self.mapper, **dict(setting.overrides)},
        )

    def describe(self) -> dict:
        """Plain-data copy in the config's layout (for table metadata)."""
        d = {f.name: getattr(self, f.name) for f in fields(self) if f.name != "mapper"}
        d.update(self.mapper)
        d["settings"] = [{"name": st.name, "known_intrinsics": st.known_intrinsics,
                          **dict(st.overrides)} for st in self.settings]
        return d


@dataclass(frozen=True)
class RunSpec:
    """One planned COLMAP run: its method name, time step (-1 = sequence) and (view, frame)s."""

    method: str
    frame: int
    keys: tuple[tuple[int, int], ...]


def evenly(values: list[int], count: int) -> list[int]:
    """``count`` values spread evenly over sorted ``values`` (first and last included)."""
    values = sorted(values)
    if count <= 0 or not values:
        return []
    if count >= len(values):
        return values
    idx = np.unique(np.round(np.linspace(0, len(values) - 1, count)).astype(int))
    return [values[i] for i in idx]


def plan_runs(frames: pd.DataFrame, cfg: CompareConfig) -> list[RunSpec]:
    """Static-rig runs (one per chosen time step) and one sequence run over a frame subsample."""
    all_frames = sorted(int(f) for f in frames["frame"].unique())
    keys = set(zip(frames["view"].astype(int), frames["frame"].astype(int)))
    views = sorted(int(v) for v in frames["view"].unique())
    steps = (list(cfg.static_frames) if cfg.static_frames is not None
             else evenly(all_frames, cfg.num_static_frames))
    runs = []
    for k in steps:
        run_keys = tuple((v, k) for v in views if (v, k) in keys)
        runs.append(RunSpec(f"colmap_static_frame_{k}", k, run_keys))
    seq = evenly(all_frames, cfg.sequence_frames)
    if seq:
        run_keys = tuple((v, f) for f in seq for v in views if (v, f) in keys)
        runs.append(RunSpec("colmap_sequence", -1, run_keys))
    return runs


class GroundTruth:
    """Ground-truth cameras by (view, frame); a static camera (frame -1) serves every frame."""

    def __init__(self, cameras: pd.DataFrame, source: str = "cameras table"):
        self.source = str(source)
        self._rows = {}
        for row in cameras.itertuples(index=False):
            self._rows[(int(row.view), int(row.frame))] = row

    def row(self, view: int, frame: int):
        row = self._rows.get((view, frame)) or self._rows.get((view, -1))
        if row is None:
            raise InputError(f"{self.source}: no camera for view {view}, frame {frame}")
        return row

    def K(self, view: int, frame: int) -> np.ndarray:
        r = self.row(view, frame)
        return np.array([[r.fx, 0, r.cx], [0, r.fy, r.cy], [0, 0, 1.0]])

    def pose(self, view: int, frame: int) -> tuple[np.ndarray, np.ndarray]:
        r = self.row(view, frame)
        return (np.asarray(r.R, float).reshape(3, 3), np.asarray(r.t, float).reshape(3))


def image_inputs(frames: pd.DataFrame, frames_dir: Path, gt: GroundTruth,
                 keys) -> list[ImageInput]:
    """ImageInputs for the (view, frame) ``keys``; image paths are relative to ``frames_dir``."""
    by_key = {(int(r.view), int(r.frame)): r for r in frames.itertuples(index=False)}
    out = []
    for view, frame in keys:
        path = frames_dir / by_key[(view, frame)].image
        if not path.exists():
            raise InputError(f"{path}: image listed in frames.parquet does not exist")
        r = gt.row(view, frame)
        out.append(ImageInput(path, view, frame, int(r.width), int(r.height), gt.K(view, frame)))
    return out


def _nan_row() -> dict:
    return dict(rot_error_deg=np.nan, rot_error_deg_max=np.nan, centre_error_m=np.nan,
                centre_error_m_max=np.nan, focal_error_pct=np.nan, alignment="")


def camera_error_columns(R_est, t_est, R_gt, t_gt) -> tuple[dict, object]:
    """Rotation / centre error columns after similarity alignment (NaN for < 2 cameras)."""
    if len(R_est) < 2:
        return _nan_row(), None
    al = align_cameras(np.stack(R_est), np.stack(t_est), np.stack(R_gt), np.stack(t_gt))
    return dict(rot_error_deg=float(al.rotation_deg.mean()),
                rot_error_deg_max=float(al.rotation_deg.max()),
                centre_error_m=float(al.centre_m.mean()),
                centre_error_m_max=float(al.centre_m.max()),
                focal_error_pct=np.nan, alignment=al.method), al


def colmap_row(scene: str, spec: RunSpec, setting: str, known_intrinsics: bool,
               images: list[ImageInput], result: ColmapResult,
               gt: GroundTruth) -> tuple[dict, object]:
    """A table row for one COLMAP run and the alignment (None when it could not be made)."""
    by_name = {im.name: im for im in images}
    R_e, t_e, R_g, t_g, focal = [], [], [], [], []
    for name, (R, t) in sorted(result.poses.items()):
        im = by_name[name]
        Rg, tg = gt.pose(im.view, im.frame)
        R_e.append(R), t_e.append(t), R_g.append(Rg), t_g.append(tg)
        fx = result.intrinsics[name][0]
        focal.append(abs(fx - im.K[0, 0]) / im.K[0, 0] * 100.0)
    ok = result.registered >= 2 and result.status == "ok"
    errors, al = camera_error_columns(R_e, t_e, R_g, t_g) if ok else (_nan_row(), None)
    if ok and not known_intrinsics and focal:
        errors["focal_error_pct"] = float(np.mean(focal))
    row = dict(scene=scene, method=spec.method, setting=setting, frame=spec.frame,
               images=len(images), registered=result.registered,
               views_registered=len({by_name[n].view for n in result.poses}),
               points3d=int(len(result.points)),
               reproj_error_px=float(result.reproj_error_px) if ok else np.nan,
               **errors, seconds=float(result.seconds), cpu_seconds=float(result.cpu_seconds),
               status=result.status, ply="")
    return row, al


def fit_rows(scene: str, fit_cameras: pd.DataFrame, gt: GroundTruth,
             fit_eval: pd.DataFrame | None) -> list[dict]:
    """The SMPL-X camera solve as one row, measured against ground truth like COLMAP's runs.

    Cameras whose ``fit_status`` is 'no_detections' carry no solved pose and are skipped.
    Seconds (the whole fit: body and cameras) and the mean reprojection error come from
    ``fit_eval`` (the fitting stage's long table: metric, part, value, seconds_total); without
    it they are NaN and the status says so. ``setting`` = fit mode + keypoint source.
    """
    R_e, t_e, R_g, t_g, focal = [], [], [], [], []
    skipped = 0
    for row in fit_cameras.to_dict("records"):
        R = np.asarray(row["R"], float).reshape(3, 3)
        t = np.asarray(row["t"], float).reshape(3)
        if row.get("fit_status") == "no_detections" or not (
                np.isfinite(R).all() and np.isfinite(t).all()):
            skipped += 1
            continue
        Rg, tg = gt.pose(int(row["view"]), int(row["frame"]))
        R_e.append(R), t_e.append(t), R_g.append(Rg), t_g.append(tg)
        fg = gt.row(int(row["view"]), int(row["frame"])).fx
        focal.append(abs(float(row["fx"]) - fg) / fg * 100.0)
    errors, _ = camera_error_columns(R_e, t_e, R_g, t_g)
    if focal:
        errors["focal_error_pct"] = float(np.mean(focal))
    seconds, cpu_seconds, reproj, notes = fit_eval_figures(fit_eval)
    if skipped:
        notes.append(f"{skipped} camera(s) without a solved pose")
    status = "ok" if len(R_e) >= 2 else f"failed: only {len(R_e)} solved camera(s)"
    if notes:
        status += " (" + "; ".join(notes) + ")"
    attrs = fit_cameras.attrs
    setting = "_".join(str(attrs[k]) for k in ("mode", "keypoints") if attrs.get(k)) or "fit"
    return [dict(scene=scene, method="smplx_camera_solve", setting=setting, frame=-1,
                 images=int(len(fit_cameras)), registered=len(R_e), views_registered=len(R_e),
                 points3d=None,
                 reproj_error_px=reproj, **errors, seconds=seconds, cpu_seconds=cpu_seconds,
                 status=status, ply="")]


def fit_eval_figures(fit_eval: pd.DataFrame | None) -> tuple[float, float, float, list[str]]:
    """(seconds, CPU seconds, mean reprojection px, notes) from the fit stage's ``fit_eval``."""
    if fit_eval is None or fit_eval.empty:
        return np.nan, np.nan, np.nan, ["no fit_eval.parquet: seconds unknown"]
    notes: list[str] = []
    seconds = cpu = reproj = np.nan
    cols = set(fit_eval.columns)
    if "seconds_total" in cols:
        seconds = float(fit_eval["seconds_total"].max())
    if {"metric", "part", "value"} <= cols:
        pick = lambda m: fit_eval.loc[(fit_eval["metric"] == m)  # noqa: E731
                                      & (fit_eval["part"] == "all"), "value"]
        if np.isnan(seconds) and len(pick("seconds")):
            seconds = float(pick("seconds").iloc[0])
        if len(pick("reprojection")):
            reproj = float(pick("reprojection").iloc[0])
        if len(pick("cpu_seconds")):
            cpu = float(pick("cpu_seconds").iloc[0])
    if np.isnan(seconds):
        notes.append("fit_eval has no seconds")
    return seconds, cpu, reproj, notes


def to_frame(rows: list[dict]) -> pd.DataFrame:
    """Rows -> the typed ``colmap_compare`` DataFrame (columns in the table's order)."""
    df = pd.DataFrame(rows, columns=list(COLMAP_COMPARE.columns))
    return df.astype({"frame": "int32", "images": "int32", "registered": "int32",
                      "views_registered": "int32", "points3d": "Int64", "seconds": "float64",
                      "cpu_seconds": "float64", "reproj_error_px": "float64"})


def compare_scene(frames: pd.DataFrame, frames_dir: str | os.PathLike, cameras: pd.DataFrame,
                  cfg: CompareConfig, threads: int = 1, ply_dir: str | os.PathLike | None = None,
                  table_dir: str | os.PathLike | None = None,
                  fit_cameras: pd.DataFrame | None = None, fit_eval: pd.DataFrame | None = None,
                  work_root: str | os.PathLike | None = None, cameras_source: str = "cameras"):
    """Run every planned COLMAP run on a scene; returns (table DataFrame, best points, colors).

    ``ply_dir``: where each successful run's points go (world frame, after the alignment);
    the table's ``ply`` column is relative to ``table_dir``. "Best" = the successful run with
    the most 3D points (an empty cloud when every run failed), for a baseline splat init.
    """
    frames_dir = Path(frames_dir)
    scene = str(frames["scene"].iloc[0]) if len(frames) else "scene"
    gt = GroundTruth(cameras, cameras_source)
    rows, best = [], (np.zeros((0, 3)), np.zeros((0, 3), np.uint8))
    if work_root is not None:
        Path(work_root).mkdir(parents=True, exist_ok=True)
    for spec in plan_runs(frames, cfg):
        images = image_inputs(frames, frames_dir, gt, spec.keys)
        # the settings of one image set share its features and matches (signsplat.colmap.run)
        with tempfile.TemporaryDirectory(prefix="colmap_shared_", dir=work_root) as share:
            for st in cfg.settings:
                log.info("%s %s (%s): %d images", scene, spec.method, st.name, len(images))
                result = run_colmap(images, cfg.options(st, threads), work_root=work_root,
                                    share_dir=share)
                row, al = colmap_row(scene, spec, st.name, st.known_intrinsics, images, result,
                                     gt)
                if al is not None and len(result.points):
                    pts = al.similarity.apply(result.points)
                    if ply_dir is not None:
                        path = Path(ply_dir) / f"{spec.method}_{st.name}.ply"
                        write_points_ply(path, pts, result.colors,
                                         comment=f"COLMAP {spec.method} {st.name}, world frame")
                        row["ply"] = os.path.relpath(path, table_dir or Path(ply_dir))
                    if len(pts) > len(best[0]):
                        best = (pts, result.colors)
                log.info("-> %s: %d/%d registered, %s points, %.1f s", row["status"],
                         row["registered"], row["images"], row["points3d"], row["seconds"])
                rows.append(row)
    if fit_cameras is not None:
        rows.extend(fit_rows(scene, fit_cameras, gt, fit_eval))
    return to_frame(rows), best[0], best[1]
