"""The ``simulate`` stage: render a synthetic signer scene with the independent mesh renderer.

:func:`simulate_scene` poses the body model along the scene's motion, renders every view and
frame with :mod:`signsplat.synth.mesh_render` (never the splat rasterizer), applies only the
effects the scene lists (:mod:`signsplat.synth.effects`) and writes, each file atomically::

    <out>/images/{view:02d}/{frame:04d}.png   RGB, 8 bit
    <out>/masks/{view:02d}/{frame:04d}.png    signer mask, 0/255 (occluders excluded)
    <out>/frames.parquet                      table 'frames'
    <out>/cameras.parquet                     table 'cameras' (frame = -1: static camera)
    <out>/smplx_gt.parquet                    table 'smplx_params' (hand_mean 'flat')
    <out>/keypoints_gt.parquet                table 'keypoints' + 'visible' (bool), 'depth' (m)

Ground-truth keypoints: the 133 COCO-WholeBody points of ``WholeBodyRegressor`` projected into
every view. ``visible``: the keypoint's pixel is in the image, and at that pixel or one of its
8 neighbours (silhouette points) the rendered surface (occluders included) is not nearer than
the keypoint by more than a tolerance: for surface keypoints (face, fingertips, ...) their
distance to the nearest posed vertex plus ``render.keypoint_tolerance``; for joint keypoints
(shoulders, elbows, hand joints, ...) twice their depth below the skin plus that slack, and
the surface seen there must be skinned to the joint, its parent or its children (the body
part around it, not another limb or an occluder in front). ``score`` = visible as float; ``depth`` = camera z (m).
Same scene and seed -> byte-identical files.
"""

from __future__ import annotations

import os
import time
from concurrent.futures import ThreadPoolExecutor
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from signsplat.io.images import write_png
from signsplat.io.tables import write_table
from signsplat.synth import mesh_render as mr
from signsplat.synth.effects import Camera, EffectChain, Prop, build_effects
from signsplat.synth.scene import build_motion, camera_rig, params_at, scene_name, scene_target

__all__ = ["SignerMesh", "ViewRender", "render_view", "project", "keypoint_visibility",
           "simulate_scene", "load_signer"]


@dataclass(frozen=True)
class SignerMesh:
    """What the renderer needs of the signer besides posed vertices.

    Attributes:
        faces: (F, 3) int64 triangles.
        canonical: (V, 3) float32 rest-pose positions used as texture coordinates.
        part_labels: (V,) int64 part of each vertex (``signsplat.body.joints.PART_*``).
        colorize: ``(points (P,3) canonical, labels (P,)) -> (P,3)`` albedo in [0, 1].
    """

    faces: np.ndarray
    canonical: np.ndarray
    part_labels: np.ndarray
    colorize: Callable[[np.ndarray, np.ndarray], np.ndarray]


@dataclass(frozen=True)
class ViewRender:
    """One rendered view: ``rgb`` (H,W,3) float32 [0,1], ``mask`` (H,W) bool signer coverage
    above one half, or one half with the pixel centre covered (:func:`coverage_mask`),
    ``depth`` (H,W) float32 nearest surface in each pixel (signer or prop, metres, inf =
    empty), ``face`` (H,W) int32 triangle of that nearest surface (signer faces first, then
    props; -1 = empty), ``coverage`` (H,W) float32 fraction of samples showing the signer."""

    rgb: np.ndarray
    mask: np.ndarray
    depth: np.ndarray
    face: np.ndarray
    coverage: np.ndarray


def coverage_mask(coverage: np.ndarray, centre: np.ndarray | None = None) -> np.ndarray:
    """(H,W) bool: the pixels the signer covers more than half of, and of those covered exactly
    half the ones whose centre the signer covers (``centre`` (H,W) bool, one sample at each
    pixel centre; None: no half-covered pixel counts).

    With an even supersampling a pixel whose centre lies within half a sample spacing of an
    edge is covered exactly half. Counting all of them would put the mask's outline that far
    outside the body's (a quarter pixel at 2 x 2 samples), none of them that far inside; the
    silhouette terms of the fit read the outline as passing midway between a mask pixel's
    centre and its outside neighbour's. The centre sample splits them along the true edge, so
    the outline stays unbiased and follows the edge without noise (an avatar trained on the
    masks must reproduce it).
    """
    coverage = np.asarray(coverage, np.float32)
    mask = coverage > 0.5
    if centre is not None:
        mask |= half_covered(coverage) & np.asarray(centre, bool)
    return mask


def half_covered(coverage: np.ndarray) -> np.ndarray:
    """(H,W) bool: the pixels the signer covers exactly half of (:func:`coverage_mask`)."""
    return np.abs(np.asarray(coverage, np.float32) - 0.5) < 1e-6


def _block_nearest(depth: np.ndarray, face: np.ndarray, s: int):
    """Per s x s block the nearest sample: depth (H,W) float32 and its face id (H,W) int32."""
    if s == 1:
        return depth, face
    h, w = depth.shape[0] // s, depth.shape[1] // s
    d = depth.reshape(h, s, w, s).transpose(0, 2, 1, 3).reshape(h, w, s * s)
    f = face.reshape(h, s, w, s).transpose(0, 2, 1, 3).reshape(h, w, s * s)
    k = np.argmin(d, axis=2)[..., None]
    return (np.take_along_axis(d, k, 2)[..., 0],
            np.where(np.isfinite(np.take_along_axis(d, k, 2)[..., 0]),
                     np.take_along_axis(f, k, 2)[..., 0], -1).astype(np.int32))


def _shade_samples(raster: mr.Raster, verts: np.ndarray, faces: np.ndarray, n_signer: int,
                   signer: SignerMesh, prop_colors: np.ndarray | None,
                   prop_normals: np.ndarray | None, chain: EffectChain,
                   cam: Camera) -> tuple[np.ndarray, np.ndarray]:
    """Colour (Hs,Ws,3) float32 and signer coverage (Hs,Ws) bool of one raster.

    ``verts``/``faces`` hold the signer followed by any props (faces >= ``n_signer``).
    """
    H, W = raster.shape
    fid_all = raster.face_id.reshape(-1)
    flat = np.flatnonzero(fid_all >= 0)
    fid = fid_all[flat]
    bary = raster.bary.reshape(-1, 3)[flat]
    shaders = chain.at("shade")
    n_vert = signer.canonical.shape[0]
    if prop_colors is None:
        sig = None  # every drawn sample is the signer
        sf, sb = fid, bary
    else:
        is_signer = fid < n_signer
        sig = np.flatnonzero(is_signer)
        prop = np.flatnonzero(~is_signer)
        sf, sb = fid[sig], bary[sig]
    # one gather for everything interpolated on the signer
    attrs = signer.canonical
    if shaders:
        vn = mr.vertex_normals(verts[:n_vert], signer.faces)
        attrs = np.concatenate([signer.canonical, vn, verts[:n_vert].astype(np.float32)], 1)
    values = mr.interpolate_at(signer.faces, attrs, sf, sb)
    labels = mr.nearest_corner(signer.faces, signer.part_labels, sf, sb)
    signer_colors = np.clip(signer.colorize(values[:, :3], labels), 0.0, 1.0)
    if sig is None:
        colors = signer_colors.astype(np.float32, copy=False)
    else:
        colors = np.empty((len(fid), 3), np.float32)
        colors[sig] = signer_colors
        colors[prop] = prop_colors[fid[prop] - n_signer]
    if shaders:
        if sig is None:
            normals, points = values[:, 3:6], values[:, 6:9]
        else:
            normals = np.empty((len(fid), 3), np.float32)
            points = np.empty((len(fid), 3), np.float32)
            normals[sig], points[sig] = values[:, 3:6], values[:, 6:9]
            normals[prop] = prop_normals[fid[prop] - n_signer]
            points[prop] = mr.interpolate_at(faces, verts, fid[prop], bary[prop])
        normals = normals / np.maximum(np.linalg.norm(normals, axis=1, keepdims=True), 1e-12)
        for effect in shaders:
            colors = effect.shade(colors, normals, points, cam)
    rgb = np.zeros((H * W, 3), np.float32)
    rgb[flat] = colors
    signer_hit = np.zeros(H * W, bool)
    signer_hit[flat if sig is None else flat[sig]] = True
    return rgb.reshape(H, W, 3), signer_hit.reshape(H, W)


def render_view(poses: Sequence[np.ndarray], weights: Sequence[float], signer: SignerMesh,
                cam: Camera, chain: EffectChain, view: int, frame: int,
                target: np.ndarray, supersample: int = 2, near: float = 0.05,
                depth_pose: np.ndarray | None = None) -> ViewRender:
    """Render the signer (and any props of geometry effects) in one camera.

    Args:
        poses: S posed vertex arrays (V, 3) world metres; S > 1 for motion blur.
        weights: (S,) weights of the poses in the colour and coverage average.
        signer: faces, texture coordinates and albedo function.
        cam: the camera of this view and frame (after camera effects).
        chain: the scene's effects (only geometry/shade/background/image hooks are used here).
        target: (3,) point the rig looks at (used to place props).
        supersample: s, samples per pixel s x s, box-filtered.
        near: near-plane depth in metres.
        depth_pose: (V, 3) pose whose nearest-surface depth is returned (default: the pose
            when S == 1; with S > 1 this extra pose is rasterized for depth only).
    """
    s = int(supersample)
    K_hi = mr.scale_intrinsics(cam.K, s)
    Wh, Hh = cam.width * s, cam.height * s
    hi_cam = Camera(K_hi, cam.R, cam.t, Wh, Hh)
    props: list[Prop] = [p for e in chain.at("geometry")
                         for p in e.geometry(cam, view, frame, target)]
    n_signer = signer.faces.shape[0]
    n_vert = signer.canonical.shape[0]
    prop_colors = prop_normals = None
    if props:
        offs = np.cumsum([n_vert] + [len(p.vertices) for p in props])[:-1]
        faces = np.concatenate([signer.faces] + [p.faces + o for p, o in zip(props, offs)])
        prop_colors = np.concatenate([np.repeat(p.color[None], len(p.faces), 0) for p in props])
        prop_normals = np.concatenate([mr.face_normals(p.vertices, p.faces) for p in props])
        prop_verts = np.concatenate([p.vertices for p in props])
    else:
        faces, prop_verts = signer.faces, None

    def scene_vertices(v):
        v = np.asarray(v, np.float64)
        return v if prop_verts is None else np.concatenate([v, prop_verts])

    acc_rgb = np.zeros((Hh, Wh, 3), np.float32)
    acc_cov = np.zeros((Hh, Wh), np.float32)  # signer samples
    acc_alpha = np.zeros((Hh, Wh), np.float32)  # signer or prop samples
    depth_hi = face_hi = None
    for v, w in zip(poses, weights):
        verts = scene_vertices(v)
        raster = mr.rasterize(verts, faces, K_hi, cam.R, cam.t, Wh, Hh, near)
        rgb, hit = _shade_samples(raster, verts, faces, n_signer, signer, prop_colors,
                                  prop_normals, chain, hi_cam)
        if len(poses) == 1:
            acc_rgb, acc_cov, depth_hi = rgb, hit.astype(np.float32), raster.depth
            face_hi = raster.face_id
            acc_alpha = raster.mask.astype(np.float32)
        else:
            acc_rgb += np.float32(w) * rgb
            acc_cov += np.float32(w) * hit
            acc_alpha += np.float32(w) * raster.mask
    if depth_hi is None:
        pose = poses[len(poses) // 2] if depth_pose is None else depth_pose
        raster = mr.rasterize(scene_vertices(pose), faces, K_hi, cam.R, cam.t, Wh, Hh, near)
        depth_hi, face_hi = raster.depth, raster.face_id
    rgb = mr.downsample(acc_rgb, s)
    coverage = mr.downsample(acc_cov, s).astype(np.float32)
    for effect in chain.at("background"):
        alpha = mr.downsample(acc_alpha, s)
        bg = effect.background(view, frame, cam.height, cam.width)
        rgb = rgb + bg * (1.0 - alpha)[..., None]
    for effect in chain.at("image"):
        rgb = effect.image(rgb, view, frame)
    rgb = np.clip(rgb, 0.0, 1.0).astype(np.float32)
    depth, face = _block_nearest(depth_hi, face_hi, s)
    centre = None
    if half_covered(coverage).any():  # one sample at each pixel centre decides them
        pose = poses[len(poses) // 2] if depth_pose is None else depth_pose
        mid = mr.rasterize(scene_vertices(pose), faces, cam.K, cam.R, cam.t, cam.width,
                           cam.height, near)
        centre = (mid.face_id >= 0) & (mid.face_id < n_signer)
    return ViewRender(rgb, coverage_mask(coverage, centre), depth, face, coverage)


# --- keypoints -----------------------------------------------------------------------------

def project(points: np.ndarray, cam: Camera, near: float = 1e-6) -> tuple[np.ndarray, np.ndarray]:
    """Project world points (N, 3) -> pixels (N, 2) float64 (NaN behind the camera), depth (N,)."""
    pc = mr.camera_depth(points, cam.R, cam.t)
    z = pc[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        uv = (pc[:, :2] / z[:, None]) * np.diag(cam.K)[:2] + cam.K[:2, 2]
    uv[z <= near] = np.nan
    return uv, z


def keypoint_visibility(uv: np.ndarray, z: np.ndarray, depth: np.ndarray,
                        tolerance: np.ndarray | float, radius: int = 1,
                        face: np.ndarray | None = None, face_joint: np.ndarray | None = None,
                        allowed: np.ndarray | None = None) -> np.ndarray:
    """Visible keypoints: inside the image and not hidden behind other surface.

    A keypoint is visible when its pixel lies in the image and some pixel within ``radius``
    (a (2r+1)^2 window; r = 1 lets silhouette points such as fingertips and ears count) shows
    a surface no nearer than the keypoint's depth minus its tolerance. Keypoints with a row in
    ``allowed`` that has any True entry (joints inside the body) must in addition see, at that
    pixel, a signer triangle whose joint (``face_joint``) is allowed for them (the body part
    around the joint, not a hand or an occluder in front of it).

    Args:
        uv: (N, 2) pixel coordinates (NaN = behind the camera).
        z: (N,) camera depth of the keypoints (m).
        depth: (H, W) nearest rendered surface per pixel (m, inf = empty).
        tolerance: scalar or (N,) slack in metres.
        radius: window half-size in pixels.
        face: (H, W) int triangle id of the nearest surface (-1 = empty); needed with allowed.
        face_joint: (F,) int joint of each signer triangle (ids >= F are props).
        allowed: (N, J) bool joints whose surface may be seen at a joint keypoint.

    Returns:
        (N,) bool. A keypoint over empty pixels only is not visible (it is not on the body).
    """
    H, W = depth.shape
    finite = np.isfinite(uv).all(axis=1)
    px = np.full(len(uv), -1, np.int64)
    py = np.full(len(uv), -1, np.int64)
    px[finite] = np.floor(uv[finite, 0] + 0.5).astype(np.int64)
    py[finite] = np.floor(uv[finite, 1] + 0.5).astype(np.int64)
    inside = finite & (px >= 0) & (px < W) & (py >= 0) & (py < H)
    tol = np.broadcast_to(np.asarray(tolerance, np.float64), z.shape)
    visible = np.zeros(len(uv), bool)
    idx = np.flatnonzero(inside)
    if allowed is not None:
        part_kp = allowed[idx].any(axis=1)
    for dy in range(-radius, radius + 1):
        for dx in range(-radius, radius + 1):
            qx, qy = px[idx] + dx, py[idx] + dy
            ok = (qx >= 0) & (qx < W) & (qy >= 0) & (qy < H)
            surf = np.full(len(idx), np.inf)
            surf[ok] = depth[qy[ok], qx[ok]]
            hit = np.isfinite(surf) & (z[idx] <= surf + tol[idx])
            if allowed is not None:
                fq = np.full(len(idx), -1, np.int64)
                fq[ok] = face[qy[ok], qx[ok]]
                on_signer = (fq >= 0) & (fq < len(face_joint))
                joint = np.where(on_signer, face_joint[np.where(on_signer, fq, 0)], 0)
                part_ok = on_signer & allowed[idx, joint]
                hit &= ~part_kp | part_ok
            visible[idx] |= hit
    return visible


# --- body ----------------------------------------------------------------------------------

def load_signer(body_path: str | os.PathLike, appearance_seed: int = 0):
    """Body model, its :class:`SignerMesh` and the keypoint regressor.

    Albedo per pixel comes from ``signsplat.body.appearance.albedo`` at canonical (rest-pose
    template) positions, with the features placed relative to the model's rest joints.
    """
    from signsplat.body.appearance import albedo
    from signsplat.body.keypoints import WholeBodyRegressor
    from signsplat.body.model import BodyModel

    model = BodyModel.from_file(body_path)
    model.eval()
    faces = model.faces.detach().cpu().numpy().astype(np.int64)
    canonical = model.v_template.detach().cpu().numpy().astype(np.float32)
    labels = model.part_labels.detach().cpu().numpy().astype(np.int64)
    joints = model.rest_joints.detach().cpu().numpy().astype(np.float64)

    def colorize(points, part_labels):
        return np.asarray(albedo(points, part_labels, appearance_seed, joints=joints), np.float32)

    signer = SignerMesh(faces, canonical, labels, colorize)
    return model, signer, WholeBodyRegressor(model)


def _pose(model, params: Mapping[str, np.ndarray], regressor=None, chunk: int = 32):
    """Posed vertices (T, V, 3) float64 and keypoints (T, 133, 3) (None without regressor)."""
    import torch

    T = len(params["betas"])
    verts, kps = [], []
    with torch.no_grad():
        for i in range(0, T, chunk):
            batch = {k: torch.as_tensor(np.asarray(v[i:i + chunk]), dtype=torch.float32)
                     for k, v in params.items()}
            out = model(**batch)
            verts.append(out.vertices.detach().cpu().numpy().astype(np.float64))
            if regressor is not None:
                kps.append(np.asarray(regressor(out).detach().cpu().numpy(), np.float64))
    return np.concatenate(verts), (np.concatenate(kps) if regressor is not None else None)


def _depth_below_skin(verts: np.ndarray, kps: np.ndarray) -> np.ndarray:
    """(T, K) distance (m) from each posed keypoint to the nearest posed mesh vertex.

    verts (T, V, 3), kps (T, K, 3). Joint keypoints sit inside the body (a hip ~10 cm, a
    finger joint ~1 cm); surface keypoints are ~0.
    """
    from scipy.spatial import cKDTree

    return np.stack([cKDTree(v).query(k)[0] for v, k in zip(verts, kps)])


def _keypoint_parts(model, regressor, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Which body part each joint keypoint may be seen on.

    Returns ``face_joint`` (F,) int64, the dominant skinning joint of each triangle, and
    ``allowed`` (K, J) bool: for a keypoint that is a model joint j (matched in the rest
    pose), the surface skinned to j, its parent or its children (the bones meeting at the
    joint: for a wrist the forearm, the palm and the finger roots); all False for surface
    keypoints.
    """
    import torch

    weights = model.lbs_weights.detach().cpu().numpy()
    vjoint = np.argmax(weights, axis=1)
    a, b, c = (vjoint[faces[:, i]] for i in range(3))
    face_joint = np.where(b == c, b, a).astype(np.int64)
    with torch.no_grad():
        out = model()
        kps = regressor(out)[0].detach().cpu().numpy()
    joints = out.joints[0].detach().cpu().numpy()
    parents = model.parents.detach().cpu().numpy()
    dist = np.linalg.norm(kps[:, None] - joints[None], axis=2)
    allowed = np.zeros((len(kps), len(joints)), bool)
    for k in np.flatnonzero(dist.min(axis=1) < 1e-6):
        j = int(np.argmin(dist[k]))
        allowed[k, j] = True
        allowed[k, parents == j] = True
        if parents[j] >= 0:
            allowed[k, parents[j]] = True
    return face_joint, allowed


# --- tables --------------------------------------------------------------------------------

def _smplx_table(params: Mapping[str, np.ndarray], scene: str) -> pd.DataFrame:
    T = len(params["betas"])
    data: dict[str, Any] = {"scene": [scene] * T, "frame": np.arange(T, dtype=np.int32)}
    for k in ("betas", "expression", "global_orient", "body_pose", "jaw_pose", "leye_pose",
              "reye_pose", "left_hand_pose", "right_hand_pose", "transl"):
        data[k] = [np.asarray(row, np.float32) for row in params[k]]
    return pd.DataFrame(data)


def _camera_rows(scene: str, view: int, frame: int, cam: Camera) -> dict[str, Any]:
    return {"scene": scene, "view": view, "frame": frame, "width": cam.width,
            "height": cam.height, "fx": float(cam.K[0, 0]), "fy": float(cam.K[1, 1]),
            "cx": float(cam.K[0, 2]), "cy": float(cam.K[1, 2]),
            "R": np.asarray(cam.R, np.float64).reshape(9), "t": np.asarray(cam.t, np.float64)}


def _cameras_table(rows: list[dict[str, Any]]) -> pd.DataFrame:
    df = pd.DataFrame(rows)
    for c in ("view", "frame", "width", "height"):
        df[c] = df[c].astype(np.int32)
    return df


# --- the stage -----------------------------------------------------------------------------

def simulate_scene(scene: Mapping[str, Any], body_path: str | os.PathLike,
                   gloss_path: str | os.PathLike | None, out_dir: str | os.PathLike,
                   threads: int = 1, progress: bool = True) -> dict[str, Any]:
    """Simulate one scene (validated spec dict) into ``out_dir``; see the module docstring.

    ``threads`` worker threads render views in parallel (the Numba kernels release the GIL);
    the files do not depend on it.

    Returns a summary: ``frames``, ``views``, ``images``, ``seconds`` (all), ``pose_seconds``
    (loading and posing), ``render_seconds`` (summed over workers: render + PNG writing +
    keypoints), ``per_view_frame`` (wall seconds after posing per image) and the paths.
    """
    import torch
    from tqdm import tqdm

    t_start = time.perf_counter()
    threads = max(1, int(threads))
    # torch poses the body in one thread: its float32 reductions split differently across
    # threads (keypoints moved by 1e-5 px between 1 and 2 threads), and the files must not
    # depend on `threads`, which only renders views side by side
    torch.set_num_threads(1)
    out = Path(out_dir)
    name = scene_name(scene, out)
    seed = int(scene.get("seed", 0))
    chain = build_effects(scene.get("effects", []), seed)
    render_cfg = scene.get("render", {})
    ss = int(render_cfg.get("supersample", 2))
    near = float(render_cfg.get("near", 0.05))
    kp_tol = float(render_cfg.get("keypoint_tolerance", 0.015))

    model, signer, regressor = load_signer(body_path, int(scene["signer"]["appearance_seed"]))
    params = build_motion(scene, gloss_path, model.num_betas, model.num_expression)
    T = len(params["betas"])
    verts, kps = _pose(model, params, regressor)
    face_joint, allowed = _keypoint_parts(model, regressor, signer.faces)
    below = _depth_below_skin(verts, kps)  # (T, 133)
    # joint keypoints: the part around them may bulge towards the camera (twice the depth
    # below the skin); surface keypoints: the skin itself
    tol = np.where(allowed.any(axis=1)[None], 2.0 * below, below) + kp_tol

    blur = chain.at("subframes")
    if blur:
        offsets, weights = blur[0].subframes()
        sub_params = [params_at(params, f + o) for f in range(T) for o in offsets]
        merged = {k: np.concatenate([p[k] for p in sub_params]) for k in params}
        sub_verts = _pose(model, merged)[0].reshape(T, len(offsets), -1, 3)
    else:
        weights = np.ones(1)
    t_pose = time.perf_counter()

    rig = camera_rig(scene["cameras"])
    target = scene_target(scene["cameras"])
    cam_effects = chain.at("camera")
    fps = float(scene["fps"])
    frame_rows, cam_rows = [], []
    kp_cols: dict[str, list[np.ndarray]] = {k: [] for k in
                                            ("view", "frame", "kp", "x", "y", "visible", "depth")}
    if not cam_effects:
        cam_rows = [_camera_rows(name, v, -1, cam) for v, cam in enumerate(rig)]
    n_kp = kps.shape[1]

    def job(f: int, v: int, cam: Camera):
        """Render, write and label one view of one frame (runs in a worker thread)."""
        t0 = time.perf_counter()
        poses = list(sub_verts[f]) if blur else [verts[f]]
        result = render_view(poses, weights, signer, cam, chain, v, f, target, ss, near,
                             depth_pose=verts[f] if blur else None)
        image, mask = f"images/{v:02d}/{f:04d}.png", f"masks/{v:02d}/{f:04d}.png"
        write_png(out / image, np.round(result.rgb * 255.0).astype(np.uint8))
        write_png(out / mask, np.where(result.mask, 255, 0).astype(np.uint8))
        uv, z = project(kps[f], cam)
        vis = keypoint_visibility(uv, z, result.depth, tol[f], face=result.face,
                                  face_joint=face_joint, allowed=allowed)
        row = {"scene": name, "view": v, "frame": f, "time": f / fps, "image": image,
               "mask": mask}
        return row, uv, z, vis, time.perf_counter() - t0

    t_render = 0.0
    with ThreadPoolExecutor(max_workers=threads) as pool:
        for f in tqdm(range(T), desc=f"simulate {name}", unit="frame", disable=not progress):
            cams = []
            for v, cam in enumerate(rig):
                for effect in cam_effects:
                    cam = effect.camera(cam, v, f)
                if cam_effects:
                    cam_rows.append(_camera_rows(name, v, f, cam))
                cams.append(cam)
            results = list(pool.map(job, [f] * len(cams), range(len(cams)), cams))
            for v, (row, uv, z, vis, seconds) in enumerate(results):
                t_render += seconds
                frame_rows.append(row)
                kp_cols["view"].append(np.full(n_kp, v, np.int32))
                kp_cols["frame"].append(np.full(n_kp, f, np.int32))
                kp_cols["kp"].append(np.arange(n_kp, dtype=np.int16))
                kp_cols["x"].append(uv[:, 0].astype(np.float32))
                kp_cols["y"].append(uv[:, 1].astype(np.float32))
                kp_cols["visible"].append(vis)
                kp_cols["depth"].append(z.astype(np.float32))

    frames = pd.DataFrame(frame_rows).astype({"view": np.int32, "frame": np.int32})
    keypoints = pd.DataFrame({k: np.concatenate(v) for k, v in kp_cols.items()})
    keypoints.insert(0, "scene", name)
    keypoints.insert(6, "score", keypoints["visible"].astype(np.float32))
    body_name = Path(body_path).name
    paths = {
        "frames": write_table(frames, out / "frames.parquet", "frames"),
        "cameras": write_table(_cameras_table(cam_rows), out / "cameras.parquet", "cameras",
                               metadata={"effects": ",".join(chain.names)}),
        "smplx": write_table(_smplx_table(params, name), out / "smplx_gt.parquet",
                             "smplx_params",
                             metadata={"hand_mean": "flat", "body_model": body_name}),
        "keypoints": write_table(keypoints, out / "keypoints_gt.parquet", "keypoints",
                                 metadata={"source": "ground truth", "body_model": body_name}),
    }
    t_end = time.perf_counter()
    n_img = T * len(rig)
    return {"scene": name, "frames": T, "views": len(rig), "images": n_img,
            "seconds": t_end - t_start, "pose_seconds": t_pose - t_start,
            "render_seconds": t_render,
            "per_view_frame": (t_end - t_pose) / max(n_img, 1), "paths": paths}
