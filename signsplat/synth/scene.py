"""Scene spec -> camera rig and SMPL-X motion (the inputs of the simulator).

A scene spec is the validated dict of ``config/scenes/<name>.yaml``
(``workflow/schemas/scene.schema.yaml``). This module turns it into

- a camera rig: :func:`camera_rig` -> list of :class:`~signsplat.synth.effects.Camera`,
  arranged on an arc or ring around ``cameras.target`` at horizontal ``distance``, centres at
  ``height``, looking at the target; vertical field of view -> ``fx = fy``, principal point at
  the image centre ``((W-1)/2, (H-1)/2)``;
- a motion: :func:`build_motion` -> dict of SMPL-X parameter blocks, each (T, k) float32,
  from glosses of the gloss library composed with holds and smooth transitions, or from an
  ``smplx_params`` Parquet table. Betas come from the signer, the global orientation is the
  identity (the signer faces +z) and the translation zero (the body stands on y = 0).
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from signsplat.body.joints import POSE_BLOCKS
from signsplat.errors import InputError, SignSplatError
from signsplat.synth.effects import Camera

__all__ = ["look_at", "camera_rig", "scene_target", "build_motion", "params_at",
           "check_scene", "scene_name", "SceneError", "ROTATION_BLOCKS"]

ROTATION_BLOCKS = tuple(name for name, _ in POSE_BLOCKS)  # axis-angle blocks
# blocks a gloss clip contributes; betas, global_orient and transl come from the scene
_CLIP_BLOCKS = ("body_pose", "jaw_pose", "leye_pose", "reye_pose", "left_hand_pose",
                "right_hand_pose", "expression")


class SceneError(SignSplatError, ValueError):
    """A scene spec refers to something that does not exist (gloss, track file)."""


# --- cameras -------------------------------------------------------------------------------

def look_at(eye: Sequence[float], target: Sequence[float],
            up: Sequence[float] = (0.0, 1.0, 0.0)) -> tuple[np.ndarray, np.ndarray]:
    """OpenCV extrinsics of a camera at ``eye`` looking at ``target`` with world ``up``.

    Returns ``R`` (3,3) float64 (rows: camera right, down, forward in world coordinates) and
    ``t`` (3,) with ``x_cam = R @ x_world + t``.
    """
    eye = np.asarray(eye, np.float64)
    forward = np.asarray(target, np.float64) - eye
    norm = np.linalg.norm(forward)
    if norm < 1e-12:
        raise SceneError("camera: eye and target coincide")
    forward /= norm
    right = np.cross(forward, np.asarray(up, np.float64))
    if np.linalg.norm(right) < 1e-9:  # looking straight up or down: pick any right vector
        right = np.cross(forward, np.array([0.0, 0.0, 1.0]))
    right /= np.linalg.norm(right)
    down = np.cross(forward, right)
    R = np.stack([right, down, forward])
    return R, -R @ eye


def scene_target(cameras: Mapping[str, Any]) -> np.ndarray:
    """(3,) float64 point the rig looks at."""
    return np.asarray(cameras["target"], np.float64)


def even_azimuths(count: int, arc_degrees: float) -> tuple[np.ndarray, float]:
    """``count`` camera azimuths (degrees) evenly over an arc centred on the signer's front,
    or over the whole ring from the front when ``arc_degrees`` >= 360; and the gap between
    neighbours (the arc itself for one camera)."""
    if arc_degrees >= 360:
        return np.arange(count) * 360.0 / count, 360.0 / count
    az = np.linspace(-arc_degrees / 2, arc_degrees / 2, count) if count > 1 else np.zeros(1)
    return az, arc_degrees / max(count - 1, 1)


def framing_fov(framing_m: float, distance_m: float) -> float:
    """Vertical field of view (degrees) whose image height covers ``framing_m`` metres at
    ``distance_m``."""
    return float(np.degrees(2 * np.arctan(framing_m / (2 * distance_m))))


def camera_rig(cameras: Mapping[str, Any]) -> list[Camera]:
    """Cameras of a scene's ``cameras`` section (defaults filled in by the schema).

    ``arc``: ``count`` cameras evenly over ``arc_degrees`` centred on the signer's front (+z);
    ``ring``: evenly over 360 degrees starting at the front. ``distance`` is measured in the
    horizontal plane from ``target``; camera centres are at y = ``height``. With ``views`` the
    cameras are placed one by one (azimuth, and optionally their own distance, height, point
    looked at and field of view); ``count`` must equal their number.
    """
    n = int(cameras["count"])
    target = scene_target(cameras)
    views = cameras.get("views")
    if views:
        if len(views) != n:
            raise SceneError(f"cameras.count is {n} but cameras.views places {len(views)} "
                             "cameras; make them equal")
        placed = [(np.deg2rad(float(v["azimuth_degrees"])), v) for v in views]
    elif cameras["layout"] == "ring":
        placed = [(a, {}) for a in np.arange(n) * (2 * np.pi / n)]
    else:
        half = np.deg2rad(float(cameras["arc_degrees"])) / 2
        placed = [(a, {}) for a in (np.linspace(-half, half, n) if n > 1 else np.zeros(1))]
    W, H = int(cameras["width"]), int(cameras["height_px"])
    rig = []
    for a, own in placed:
        d = float(own.get("distance", cameras["distance"]))
        fov = float(own.get("fov_degrees", cameras["fov_degrees"]))
        f = 0.5 * H / np.tan(np.deg2rad(fov) / 2)
        K = np.array([[f, 0.0, (W - 1) / 2], [0.0, f, (H - 1) / 2], [0.0, 0.0, 1.0]])
        eye = np.array([target[0] + d * np.sin(a), float(own.get("height", cameras["height"])),
                        target[2] + d * np.cos(a)])
        R, t = look_at(eye, np.asarray(own.get("target", target), np.float64))
        rig.append(Camera(K, R, t, W, H))
    return rig


# --- motion --------------------------------------------------------------------------------

def _slerp_rotvec(a: np.ndarray, b: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Per-joint SLERP between axis-angle rows a, b (k,) (k = 3J) at weights w (n,) -> (n, k)."""
    import roma
    import torch

    ta = torch.as_tensor(a.reshape(-1, 3), dtype=torch.float64)
    tb = torch.as_tensor(b.reshape(-1, 3), dtype=torch.float64)
    out = roma.rotvec_slerp(ta, tb, torch.as_tensor(w, dtype=torch.float64))
    return out.reshape(len(w), -1).numpy()


def _resample(track: np.ndarray, src_fps: float, dst_fps: float) -> np.ndarray:
    """Linear resampling of a (N, k) track from ``src_fps`` to ``dst_fps``."""
    if abs(src_fps - dst_fps) < 1e-9 or len(track) < 2:
        return track
    duration = (len(track) - 1) / src_fps
    n = int(round(duration * dst_fps)) + 1
    t_src = np.arange(len(track)) / src_fps
    t_dst = np.arange(n) / dst_fps
    return np.stack([np.interp(t_dst, t_src, track[:, j]) for j in range(track.shape[1])], 1)


def _stitch(clips, hold_frames: int, transition_frames: int) -> dict[str, np.ndarray]:
    """Compose gloss clips with ``signsplat.motion.stitching.stitch_clips`` (SLERP + cubic ease).

    ``hold_frames`` holds the first and last pose of every gloss; ``transition_frames`` is the
    shortest transition (the stitcher lengthens transitions with large joint motion).
    """
    from signsplat.motion.stitching import StitchConfig, stitch_clips

    config = StitchConfig(hold_start=hold_frames, hold_end=hold_frames,
                          min_transition=transition_frames,
                          max_transition=max(transition_frames, StitchConfig.max_transition))
    out = stitch_clips(clips, config)
    return {k: np.asarray(v, np.float64) for k, v in out.items() if k in _CLIP_BLOCKS}


def _gloss_tracks(names: Sequence[str], gloss_path: str | os.PathLike, fps: float,
                  hold_frames: int, transition_frames: int) -> dict[str, np.ndarray]:
    from signsplat.motion.clips import load_gloss_library

    library = load_gloss_library(gloss_path)
    missing = [g for g in names if g not in library]
    if missing:
        raise SceneError(f"motion.glosses: unknown gloss(es) {missing} in {gloss_path}; "
                         f"known: {', '.join(sorted(library))}")
    clips = []
    for g in names:
        clip = library[g]
        if clip.hand_mean != "flat":
            raise SceneError(f"motion.glosses: gloss {g!r} stores hand poses relative to the "
                             f"MANO mean ({clip.hand_mean!r}); the simulator needs 'flat'")
        # writable float32 copies (tables read from Parquet are read-only), resampled to fps
        clips.append(replace(clip, fps=fps, poses={
            k: _resample(np.asarray(v, np.float64), float(clip.fps), fps).astype(np.float32)
            for k, v in clip.poses.items()}))
    return _stitch(clips, hold_frames, transition_frames)


def _table_tracks(path: str | os.PathLike) -> dict[str, np.ndarray]:
    from signsplat.io.tables import read_table

    df = read_table(path, "smplx_params").sort_values("frame")
    if df.empty:
        raise InputError(f"{path}: smplx_params table has no rows")
    out = {}
    for col in [*ROTATION_BLOCKS, "expression", "transl", "betas"]:
        if col in df.columns:
            out[col] = np.stack([np.asarray(v, np.float64) for v in df[col]])
    return out


def _fit(a: np.ndarray | None, T: int, k: int) -> np.ndarray:
    """(T, k) float32 from a (T, j) track: truncated or zero-padded to k columns."""
    out = np.zeros((T, k), np.float32)
    if a is not None and a.size:
        a = np.asarray(a, np.float32).reshape(T, -1)
        m = min(k, a.shape[1])
        out[:, :m] = a[:, :m]
    return out


def build_motion(scene: Mapping[str, Any], gloss_path: str | os.PathLike | None,
                 num_betas: int = 10, num_expression: int = 10) -> dict[str, np.ndarray]:
    """SMPL-X parameters of every frame of a scene: dict block -> (T, k) float32.

    Blocks: ``betas`` (T, num_betas), ``expression`` (T, num_expression), the pose blocks of
    :data:`signsplat.body.joints.POSE_BLOCKS` and ``transl`` (T, 3). ``T`` is the motion's
    length capped at ``max_frames``.
    """
    motion = scene["motion"]
    if motion.get("tracks"):
        tracks = _table_tracks(motion["tracks"])
    elif motion.get("glosses"):
        if gloss_path is None:
            raise SceneError("motion.glosses needs a gloss library (--glosses)")
        tracks = _gloss_tracks(motion["glosses"], gloss_path, float(scene["fps"]),
                               int(motion["hold_frames"]), int(motion["transition_frames"]))
    else:
        raise SceneError("motion: give either 'glosses' (a list of gloss names) or 'tracks' "
                         "(an smplx_params Parquet path)")
    T = max(len(v) for v in tracks.values())
    if scene.get("max_frames"):
        T = min(T, int(scene["max_frames"]))
    tracks = {k: np.asarray(v)[:T] for k, v in tracks.items()}
    out: dict[str, np.ndarray] = {}
    betas = np.asarray(scene["signer"]["betas"], np.float32)
    out["betas"] = _fit(np.broadcast_to(betas, (T, len(betas))), T, num_betas)
    expr = tracks.get("expression")
    out["expression"] = _fit(expr, T, num_expression) * np.float32(
        scene["signer"]["expression_scale"])
    for name, k in POSE_BLOCKS:
        out[name] = _fit(tracks.get(name), T, k)
    out["transl"] = _fit(tracks.get("transl"), T, 3)
    if not motion.get("tracks"):
        out["global_orient"][:] = 0.0
        out["transl"][:] = 0.0
    return out


def params_at(params: Mapping[str, np.ndarray], time: float) -> dict[str, np.ndarray]:
    """Parameters at a fractional frame index ``time`` (clamped to the track), each (1, k).

    Axis-angle blocks are SLERPed per joint between the neighbouring frames, others linear.
    """
    T = len(next(iter(params.values())))
    time = float(np.clip(time, 0, T - 1))
    i0 = int(np.floor(time))
    i1 = min(i0 + 1, T - 1)
    w = time - i0
    out = {}
    for k, v in params.items():
        a, b = np.asarray(v[i0], np.float64), np.asarray(v[i1], np.float64)
        if w == 0.0 or i0 == i1:
            out[k] = a[None].astype(np.float32)
        elif k in ROTATION_BLOCKS:
            out[k] = _slerp_rotvec(a, b, np.array([w])).astype(np.float32)
        else:
            out[k] = ((1 - w) * a + w * b)[None].astype(np.float32)
    return out


def scene_name(scene: Mapping[str, Any], out_dir: str | os.PathLike) -> str:
    """The scene's name, or the folder above ``out_dir`` (``results/<scene>/sim``)."""
    if scene.get("name"):
        return str(scene["name"])
    out = Path(out_dir).resolve()
    return out.parent.name if out.name == "sim" else out.name


def check_scene(scene: Mapping[str, Any], source: str = "<scene>") -> None:
    """Checks beyond the schema that need no data files: effect names and options, and that
    ``cameras.views`` places ``cameras.count`` cameras.

    Raises :class:`SceneError` naming ``source`` and the problem (cheap: builds nothing but
    the listed effects' option dicts).
    """
    from signsplat.synth.effects import EffectError, build_effects

    cams = scene.get("cameras", {})
    if cams.get("views") and len(cams["views"]) != cams.get("count"):
        raise SceneError(f"{source}: cameras.count is {cams.get('count')} but cameras.views "
                         f"places {len(cams['views'])} cameras; make them equal")
    try:
        build_effects(scene.get("effects", []), int(scene.get("seed", 0)))
    except EffectError as exc:
        raise SceneError(f"{source}: {exc}") from None
