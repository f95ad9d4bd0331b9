"""One COLMAP structure-from-motion run with pycolmap 4.x: SIFT, exhaustive matching, mapping.

A run takes a list of :class:`ImageInput` (the C views of one time step for a static sparse
rig, or views x frames of a sequence) and returns a :class:`ColmapResult`. COLMAP failing is a
result, not an exception: fewer than two images registered, an exception raised by pycolmap or
even a process abort inside the C++ code end up in ``ColmapResult.status``.

Runs of the same images under several settings share work through a ``share_dir``: SIFT
features depend only on ``max_num_features``, and the matches on that and the cameras (known
or estimated intrinsics), so a later run copies the database an earlier one left there instead
of extracting or matching again. A run's ``seconds`` count the shared steps as long as they
took when they were made: the cost of that run alone.

Conventions: poses are returned in the project's OpenCV convention (``x_cam = R @ x + t``,
which is COLMAP's ``cam_from_world``) and intrinsics with pixel centres at integer coordinates
(COLMAP puts them at +0.5, so ``cx_opencv = cx_colmap - 0.5``). The reconstruction's frame
and scale are COLMAP's own (see :mod:`signsplat.colmap.align` to compare with ground truth).
"""

from __future__ import annotations

import json
import multiprocessing as mp
import os
import shutil
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

# pycolmap raises ValueError for failed checks and RuntimeError/OSError for I/O trouble.
PYCOLMAP_ERRORS = (RuntimeError, ValueError, OSError)


@dataclass(frozen=True)
class ColmapOptions:
    """Knobs of one run. The SIFT and mapper thresholds have no default here: the workflow's
    come from the ``colmap`` config section (:meth:`signsplat.colmap.compare.CompareConfig.options`).

    max_num_features: SIFT features per image.
    min_num_matches, init_min_num_inliers, init_min_tri_angle (degrees), abs_pose_min_num_inliers,
        abs_pose_min_inlier_ratio: mapper thresholds (pair verification, initial pair, adding
        an image); min_model_size: smaller models are discarded (COLMAP caps it at 80 % of
        the images).
    known_intrinsics: use the given pinhole K per image and keep it fixed in bundle adjustment;
        otherwise COLMAP's default (SIMPLE_RADIAL, focal guessed from the image size, refined).
    num_threads: threads for extraction, matching and mapping (-1 = all cores).
    seed: random seed of the mapper (reproducible runs).
    max_runtime_seconds: wall-clock cap of the mapping step (-1 = none).
    isolate: run pycolmap in a child process, so that an abort in C++ is recorded, not fatal.
    timeout_seconds: the child is killed after this long (only with ``isolate``).
    """

    max_num_features: int
    min_num_matches: int
    init_min_num_inliers: int
    init_min_tri_angle: float
    abs_pose_min_num_inliers: int
    abs_pose_min_inlier_ratio: float
    min_model_size: int
    known_intrinsics: bool = True
    num_threads: int = 1
    seed: int = 0
    max_runtime_seconds: float = -1.0
    isolate: bool = True
    timeout_seconds: float = 1800.0


@dataclass(frozen=True)
class ImageInput:
    """One input image: its file, which camera (view) took it, and the pinhole intrinsics.

    ``K`` is the (3,3) OpenCV intrinsic matrix in pixels (used with ``known_intrinsics``).
    Images with the same ``view`` share one COLMAP camera (same physical device).
    """

    path: Path
    view: int
    frame: int
    width: int
    height: int
    K: np.ndarray

    @property
    def name(self) -> str:
        """COLMAP image name: ``{view:02d}/{frame:04d}.png`` (folder = camera)."""
        return f"{self.view:02d}/{self.frame:04d}.png"


@dataclass
class ColmapResult:
    """What came out of a run (COLMAP's frame and scale).

    poses: image name -> (R (3,3), t (3,)) world-to-camera, for registered images only.
    intrinsics: image name -> (fx, fy, cx, cy) in pixels, OpenCV pixel centres.
    points: (N,3) float64 3D points; colors: (N,3) uint8 RGB.
    reproj_error_px: mean reprojection error over all observations (NaN when none).
    seconds: wall-clock time of extraction + matching + mapping; cpu_seconds: CPU time of the
        same steps over all threads (steadier than wall time on a shared machine).
    status: 'ok', or 'failed: ...' / 'error: ...' / 'crashed: ...' with the reason.
    """

    num_images: int
    poses: dict[str, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)
    intrinsics: dict[str, tuple[float, float, float, float]] = field(default_factory=dict)
    points: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    colors: np.ndarray = field(default_factory=lambda: np.zeros((0, 3), np.uint8))
    reproj_error_px: float = float("nan")
    num_models: int = 0
    num_features: int = 0
    num_verified_pairs: int = 0  # image pairs with >= min_num_matches geometric inliers
    num_initial_pairs: int = 0  # initial pairs the mapper started a model from
    seconds: float = float("nan")
    cpu_seconds: float = float("nan")
    status: str = "ok"

    @property
    def registered(self) -> int:
        return len(self.poses)


def _stage_images(images: list[ImageInput], image_dir: Path) -> None:
    """Link (or copy) the inputs into ``image_dir/{view:02d}/{frame:04d}.png``."""
    for im in images:
        dst = image_dir / im.name
        dst.parent.mkdir(parents=True, exist_ok=True)
        try:
            os.symlink(Path(im.path).resolve(), dst)
        except OSError:
            shutil.copyfile(im.path, dst)


def _set_known_intrinsics(pycolmap, db_path: Path, images: list[ImageInput]) -> None:
    """Replace each extracted camera by a PINHOLE camera with the given K (COLMAP pixel centres)."""
    by_name = {im.name: im for im in images}
    db = pycolmap.Database.open(str(db_path))
    try:
        done = set()
        for image in db.read_all_images():
            im = by_name[image.name]
            if image.camera_id in done:
                continue
            K = np.asarray(im.K, float)
            cam = pycolmap.Camera(
                camera_id=image.camera_id, model="PINHOLE", width=im.width, height=im.height,
                params=[K[0, 0], K[1, 1], K[0, 2] + 0.5, K[1, 2] + 0.5],
                has_prior_focal_length=True,
            )
            db.update_camera(cam)
            done.add(image.camera_id)
    finally:
        db.close()


def _pipeline_options(pycolmap, options: ColmapOptions):
    pipe = pycolmap.IncrementalPipelineOptions()
    pipe.min_num_matches = options.min_num_matches
    pipe.min_model_size = options.min_model_size
    pipe.num_threads = options.num_threads
    pipe.random_seed = options.seed
    pipe.max_runtime_seconds = int(options.max_runtime_seconds)
    pipe.mapper.init_min_num_inliers = options.init_min_num_inliers
    pipe.mapper.init_min_tri_angle = options.init_min_tri_angle
    pipe.mapper.abs_pose_min_num_inliers = options.abs_pose_min_num_inliers
    pipe.mapper.abs_pose_min_inlier_ratio = options.abs_pose_min_inlier_ratio
    pipe.mapper.random_seed = options.seed
    pipe.mapper.num_threads = options.num_threads
    if options.known_intrinsics:
        pipe.ba_refine_focal_length = False
        pipe.ba_refine_principal_point = False
        pipe.ba_refine_extra_params = False
        pipe.mapper.abs_pose_refine_focal_length = False
        pipe.mapper.abs_pose_refine_extra_params = False
    return pipe


def _camera_opencv(camera) -> tuple[float, float, float, float]:
    return (float(camera.focal_length_x), float(camera.focal_length_y),
            float(camera.principal_point_x) - 0.5, float(camera.principal_point_y) - 0.5)


def _collect(rec, result: ColmapResult) -> None:
    """Fill poses, intrinsics, points and the reprojection error from a Reconstruction."""
    for image in rec.images.values():
        if not image.has_pose:
            continue
        cfw = image.cam_from_world()
        R = np.asarray(cfw.rotation.matrix(), float).reshape(3, 3)
        t = np.asarray(cfw.translation, float).reshape(3)
        result.poses[image.name] = (R, t)
        result.intrinsics[image.name] = _camera_opencv(rec.cameras[image.camera_id])
    pts = list(rec.points3D.values())
    if pts:
        result.points = np.array([p.xyz for p in pts], float).reshape(-1, 3)
        result.colors = np.array([p.color for p in pts], np.uint8).reshape(-1, 3)
    if pts and result.poses:
        result.reproj_error_px = float(rec.compute_mean_reprojection_error())


def _shared_names(options: ColmapOptions) -> tuple[str, str]:
    """Names in a ``share_dir`` of the database with the features of ``options`` and of the
    one with their matches too."""
    cams = "known" if options.known_intrinsics else "estimated"
    return (f"features_{options.max_num_features}",
            f"matches_{options.max_num_features}_{cams}")


def _store(share: Path, name: str, db_path: Path, seconds: float, cpu_seconds: float) -> None:
    """Leave a copy of the database in ``share`` with the time it took to make (the JSON
    written last marks it complete)."""
    tmp = share / f".{name}.db.tmp"
    shutil.copyfile(db_path, tmp)
    os.replace(tmp, share / f"{name}.db")
    tmp = share / f".{name}.json.tmp"
    tmp.write_text(json.dumps({"seconds": seconds, "cpu_seconds": cpu_seconds}))
    os.replace(tmp, share / f"{name}.json")


def _restore(share: Path | None, name: str, db_path: Path) -> tuple[float, float] | None:
    """Copy a stored database to ``db_path``: the seconds and CPU seconds it took to make, or
    None when ``share`` has none of that name."""
    if share is None or not (share / f"{name}.json").exists():
        return None
    spent = json.loads((share / f"{name}.json").read_text())
    shutil.copyfile(share / f"{name}.db", db_path)
    return float(spent["seconds"]), float(spent["cpu_seconds"])


def _matched_database(pycolmap, images: list[ImageInput], image_dir: Path, db_path: Path,
                      options: ColmapOptions, share: Path | None) -> tuple[float, float]:
    """Features and verified matches of ``images`` in ``db_path``: made here, or copied from
    ``share`` where an earlier run left them (and left there for later runs). Returns the
    seconds and CPU seconds the copied steps took when they were made."""
    features, matches = _shared_names(options)
    done = _restore(share, matches, db_path)
    if done is not None:
        return done
    t0, c0 = time.perf_counter(), time.process_time()
    before = _restore(share, features, db_path)
    if before is None:
        extraction = pycolmap.FeatureExtractionOptions()
        extraction.num_threads = options.num_threads
        extraction.sift.max_num_features = options.max_num_features
        pycolmap.extract_features(
            str(db_path), str(image_dir), image_names=[im.name for im in images],
            camera_mode=pycolmap.CameraMode.PER_FOLDER,
            reader_options=pycolmap.ImageReaderOptions(), extraction_options=extraction,
            device=pycolmap.Device.cpu,
        )
        if share is not None:
            _store(share, features, db_path, time.perf_counter() - t0, time.process_time() - c0)
        before = (0.0, 0.0)
    if options.known_intrinsics:
        _set_known_intrinsics(pycolmap, db_path, images)
    matching = pycolmap.FeatureMatchingOptions()
    matching.num_threads = options.num_threads
    pycolmap.match_exhaustive(
        str(db_path), matching_options=matching,
        pairing_options=pycolmap.ExhaustivePairingOptions(),
        verification_options=pycolmap.TwoViewGeometryOptions(), device=pycolmap.Device.cpu,
    )
    if share is not None:
        _store(share, matches, db_path, before[0] + time.perf_counter() - t0,
               before[1] + time.process_time() - c0)
    return before


def run_colmap_inline(images: list[ImageInput], work_dir: str | os.PathLike,
                      options: ColmapOptions,
                      share_dir: str | os.PathLike | None = None) -> ColmapResult:
    """Run COLMAP in this process inside ``work_dir`` (an empty folder the caller owns).

    ``share_dir``: a folder for these images alone whose stored features and matches are
    reused and left for later runs (module docstring). pycolmap's log goes to this process's
    stderr. Exceptions raised by pycolmap are caught and recorded in ``status``; a C++ abort
    would end the process (see :func:`run_colmap`).
    """
    import pycolmap

    work = Path(work_dir)
    image_dir, db_path, sparse = work / "images", work / "database.db", work / "sparse"
    sparse.mkdir(parents=True, exist_ok=True)
    result = ColmapResult(num_images=len(images))
    if len(images) < 2:
        result.status = f"failed: {len(images)} input image(s), need at least 2"
        result.seconds = result.cpu_seconds = 0.0
        return result
    _stage_images(images, image_dir)
    share = Path(share_dir) if share_dir is not None else None
    t0, c0 = time.perf_counter(), time.process_time()
    earlier = (0.0, 0.0)  # seconds and CPU seconds of the steps copied from share_dir
    try:
        earlier = _matched_database(pycolmap, images, image_dir, db_path, options, share)
        db = pycolmap.Database.open(str(db_path))
        try:
            result.num_features = int(db.num_keypoints())
            _, inliers = db.read_two_view_geometry_num_inliers()
            result.num_verified_pairs = int(sum(n >= options.min_num_matches for n in inliers))
        finally:
            db.close()
        starts: list[int] = []
        recs = pycolmap.incremental_mapping(
            str(db_path), str(image_dir), str(sparse), _pipeline_options(pycolmap, options),
            initial_image_pair_callback=lambda: starts.append(1))
        result.num_initial_pairs = len(starts)
    except PYCOLMAP_ERRORS as exc:
        result.seconds = earlier[0] + time.perf_counter() - t0
        result.cpu_seconds = earlier[1] + time.process_time() - c0
        result.status = f"error: {type(exc).__name__}: {str(exc).strip()[:300]}"
        return result
    result.seconds = earlier[0] + time.perf_counter() - t0
    result.cpu_seconds = earlier[1] + time.process_time() - c0
    result.num_models = len(recs)
    if recs:
        best = max(recs.values(), key=lambda r: (r.num_reg_images(), r.num_points3D()))
        _collect(best, result)
    if result.registered < 2:
        if not recs and not result.num_initial_pairs:
            why = "no initial image pair found"
        elif not recs:
            why = (f"{result.num_initial_pairs} model(s) started but none kept (too few "
                   "images registered)")
        else:
            why = f"only {result.registered} image(s) registered"
        result.status = (f"failed: {why} ({result.num_features} SIFT features, "
                         f"{result.num_verified_pairs} verified pairs)")
    return result


def _child(conn, images, work_dir, options, share_dir) -> None:
    """Child-process entry: run inline and send the result back through ``conn``."""
    try:
        conn.send(run_colmap_inline(images, work_dir, options, share_dir))
    finally:
        conn.close()


def run_colmap(images: list[ImageInput], options: ColmapOptions,
               work_root: str | os.PathLike | None = None, keep: bool = False,
               share_dir: str | os.PathLike | None = None) -> ColmapResult:
    """Run COLMAP on ``images`` in a fresh temporary folder (under ``work_root`` if given).

    With ``options.isolate`` pycolmap runs in a spawned child process: if it aborts or exceeds
    ``options.timeout_seconds`` the result has status 'crashed: ...' or 'failed: timeout'.
    The temporary folder is removed unless ``keep``. ``share_dir``: see
    :func:`run_colmap_inline` (the caller owns and removes it).
    """
    if work_root is not None:
        Path(work_root).mkdir(parents=True, exist_ok=True)
    work = Path(tempfile.mkdtemp(prefix="colmap_", dir=work_root))
    try:
        if not options.isolate:
            return run_colmap_inline(images, work, options, share_dir)
        ctx = mp.get_context("spawn")
        recv, send = ctx.Pipe(duplex=False)
        share = None if share_dir is None else str(share_dir)
        proc = ctx.Process(target=_child, args=(send, images, str(work), options, share),
                           daemon=True)
        t0 = time.perf_counter()
        proc.start()
        send.close()
        result, status = None, None
        try:
            if recv.poll(options.timeout_seconds):
                result = recv.recv()
            else:
                status = f"failed: timeout after {options.timeout_seconds:.1f} s"
                proc.kill()
        except EOFError:
            pass  # the child died before sending anything
        finally:
            recv.close()
            proc.join(timeout=10)
            if proc.is_alive():
                proc.kill()
                proc.join()
        if result is None:
            result = ColmapResult(num_images=len(images),
                                  seconds=time.perf_counter() - t0)
            result.status = status or (f"crashed: pycolmap process died with exit code "
                                       f"{proc.exitcode}")
        return result
    finally:
        if not keep:
            shutil.rmtree(work, ignore_errors=True)
