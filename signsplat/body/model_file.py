"""Body-model files in the official SMPL-X ``.npz`` layout: checked loading and atomic writing.

Required arrays (V vertices, F faces, J = 55 joints):

==================  ===========  ==========================================================
key                 shape        meaning
==================  ===========  ==========================================================
v_template          (V, 3)       rest-pose template vertices, metres
f                   (F, 3)       triangle vertex indices
shapedirs           (V, 3, N)    shape (first S) then expression (next E) blend shapes
posedirs            (V, 3, 486)  pose-corrective blend shapes, 486 = 54 joints * 9
J_regressor         (55, V)      joint regressor (rest joints = J_regressor @ v_shaped)
weights             (V, 55)      linear-blend-skinning weights
kintree_table       (2, 55)      row 0: parent of each joint (root: -1 or 2**32-1)
hands_componentsl   (45, 45)     left-hand PCA components (rows)
hands_componentsr   (45, 45)     right-hand PCA components
hands_meanl         (45,)        left-hand mean pose (MANO "relaxed" pose), axis-angle
hands_meanr         (45,)        right-hand mean pose
lmk_faces_idx       (51,)        faces of the 51 static face landmarks
lmk_bary_coords     (51, 3)      barycentric coordinates of those landmarks
==================  ===========  ==========================================================

The split of ``shapedirs`` into shape and expression directions: official v1.1 files hold
400 = 300 + 100, older ones 20 = 10 + 10; our own files may state it explicitly in the
extra keys ``num_shape_dirs`` / ``num_expression_dirs`` (scalars).

Optional arrays kept when present: ``dynamic_lmk_faces_idx`` (79, 17),
``dynamic_lmk_bary_coords`` (79, 17, 3), ``joint2num``, ``part2num``, ``vt``, ``ft``, and our
extras ``part_labels`` (V,), ``vertex_colors`` (V, 3), ``kp_names`` / ``kp_faces_idx`` /
``kp_bary_coords`` or ``kp_vertex_names`` / ``kp_vertex_ids``
(named keypoint vertices for the whole-body regressor).
"""

from __future__ import annotations

import os
import zipfile
from pathlib import Path

import numpy as np

from signsplat.body.joints import NUM_JOINTS
from signsplat.errors import InputError
from signsplat.io.atomic import atomic_path

NUM_POSE_FEATURES = (NUM_JOINTS - 1) * 9  # 486
ROOT_PARENT_OFFICIAL = 2**32 - 1

# key -> shape spec; 'V', 'F', 'N' are symbols bound on first use, ints are exact sizes.
REQUIRED_KEYS: dict[str, tuple] = {
    "v_template": ("V", 3),
    "f": ("F", 3),
    "shapedirs": ("V", 3, "N"),
    "posedirs": ("V", 3, NUM_POSE_FEATURES),
    "J_regressor": (NUM_JOINTS, "V"),
    "weights": ("V", NUM_JOINTS),
    "kintree_table": (2, NUM_JOINTS),
    "hands_componentsl": (45, 45),
    "hands_componentsr": (45, 45),
    "hands_meanl": (45,),
    "hands_meanr": (45,),
    "lmk_faces_idx": (51,),
    "lmk_bary_coords": (51, 3),
}

OPTIONAL_KEYS: dict[str, tuple] = {
    "dynamic_lmk_faces_idx": (None, 17),
    "dynamic_lmk_bary_coords": (None, 17, 3),
    "part_labels": ("V",),
    "vertex_colors": ("V", 3),
    "num_shape_dirs": (),
    "num_expression_dirs": (),
}


class BodyModelFileError(InputError):
    """A body-model file is missing, unreadable, lacks a key or holds a wrongly shaped array."""


def _check_shape(path: Path, key: str, arr: np.ndarray, spec: tuple, sizes: dict) -> None:
    expected = []
    for dim in spec:
        expected.append(sizes.get(dim, dim) if isinstance(dim, str) else dim)
    ok = arr.ndim == len(spec)
    if ok:
        for dim, n in zip(spec, arr.shape):
            if isinstance(dim, str):
                if dim in sizes and sizes[dim] != n:
                    ok = False
            elif dim is not None and dim != n:
                ok = False
    if not ok:
        shown = tuple("?" if d is None else d for d in expected)
        raise BodyModelFileError(
            f"{path}: array '{key}' has shape {tuple(arr.shape)}, expected {shown}"
        )
    for dim, n in zip(spec, arr.shape):
        if isinstance(dim, str):
            sizes.setdefault(dim, n)


def _read_npz(path: Path) -> dict[str, np.ndarray]:
    if not path.exists():
        raise BodyModelFileError(f"{path}: body-model file not found")
    try:
        npz = np.load(path, allow_pickle=False)
    except (OSError, ValueError, zipfile.BadZipFile) as exc:
        raise BodyModelFileError(f"{path}: not a readable .npz body-model file ({exc})") from exc
    out = {}
    with npz:
        for key in npz.files:
            try:
                out[key] = npz[key]
            except ValueError as exc:
                if "pickle" not in str(exc).lower():
                    raise BodyModelFileError(f"{path}: cannot read array '{key}' ({exc})") from exc
                if key in REQUIRED_KEYS or key in OPTIONAL_KEYS:
                    raise BodyModelFileError(
                        f"{path}: array '{key}' is stored as Python objects (pickle, e.g. chumpy); "
                        "refusing to unpickle. Convert the file to plain numpy arrays, e.g. "
                        "re-save every array with np.asarray(...) in a trusted environment."
                    ) from exc
                # optional object arrays we do not use (e.g. chumpy leftovers) are skipped
    return out


def split_shapedirs(arrays: dict[str, np.ndarray]) -> tuple[int, int]:
    """Number of (shape, expression) directions stored in ``arrays['shapedirs']``."""
    n = int(arrays["shapedirs"].shape[2])
    if "num_shape_dirs" in arrays:
        s = int(arrays["num_shape_dirs"])
        e = int(arrays.get("num_expression_dirs", n - s))
        if s + e != n:
            raise ValueError(f"num_shape_dirs {s} + num_expression_dirs {e} != shapedirs {n}")
        return s, e
    if n == 400:
        return 300, 100
    if n == 20:
        return 10, 10
    if n > 300:
        return 300, n - 300
    # unknown layout: treat everything as shape directions (no expression space)
    return n, 0


def load_model_arrays(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """Load and check a body-model ``.npz`` in the official SMPL-X layout.

    Returns every readable array (plain numpy). ``kintree_table`` is normalised to int64 with
    the root parent as -1; ``f``, ``lmk_faces_idx`` to int64; float arrays keep their dtype.
    Raises :class:`BodyModelFileError` naming the file and key when a required key is missing,
    an array has the wrong shape, indices are out of range, or the file needs unpickling.
    """
    path = Path(path)
    arrays = _read_npz(path)
    missing = [k for k in REQUIRED_KEYS if k not in arrays]
    if missing:
        raise BodyModelFileError(
            f"{path}: missing required key(s) {missing} (official SMPL-X .npz layout; "
            f"required: {list(REQUIRED_KEYS)})"
        )
    sizes: dict = {}
    for key, spec in REQUIRED_KEYS.items():
        _check_shape(path, key, arrays[key], spec, sizes)
    for key, spec in OPTIONAL_KEYS.items():
        if key in arrays:
            _check_shape(path, key, arrays[key], spec, sizes)
    for key in REQUIRED_KEYS:
        if not np.issubdtype(arrays[key].dtype, np.number):
            raise BodyModelFileError(f"{path}: array '{key}' has dtype {arrays[key].dtype}, "
                                     "expected a numeric array")
    V = sizes["V"]
    kin = arrays["kintree_table"].astype(np.int64)
    kin[kin == ROOT_PARENT_OFFICIAL] = -1
    kin[0, 0] = -1 if kin[0, 0] in (-1, ROOT_PARENT_OFFICIAL) else kin[0, 0]
    parents = kin[0]
    later = parents[1:] >= np.arange(1, NUM_JOINTS)
    if parents[0] != -1 or np.any(parents[1:] < 0) or np.any(later):
        raise BodyModelFileError(f"{path}: 'kintree_table' row 0 is not a valid parent list "
                                 f"(root -1, every parent before its child): {parents.tolist()}")
    arrays["kintree_table"] = kin
    faces = arrays["f"].astype(np.int64)
    if faces.min() < 0 or faces.max() >= V:
        raise BodyModelFileError(f"{path}: 'f' indexes vertices {faces.min()}..{faces.max()}, "
                                 f"expected 0..{V - 1}")
    arrays["f"] = faces
    lmk = arrays["lmk_faces_idx"].astype(np.int64)
    if lmk.min() < 0 or lmk.max() >= faces.shape[0]:
        raise BodyModelFileError(f"{path}: 'lmk_faces_idx' out of range 0..{faces.shape[0] - 1}")
    arrays["lmk_faces_idx"] = lmk
    for key, limit in (("dynamic_lmk_faces_idx", faces.shape[0]), ("kp_faces_idx", faces.shape[0]),
                       ("kp_vertex_ids", V)):
        if key in arrays:
            idx = np.asarray(arrays[key]).astype(np.int64)
            if idx.size and (idx.min() < 0 or idx.max() >= limit):
                raise BodyModelFileError(f"{path}: '{key}' out of range 0..{limit - 1}")
            arrays[key] = idx
    try:
        split_shapedirs(arrays)
    except ValueError as exc:
        raise BodyModelFileError(f"{path}: {exc}") from exc
    for key in ("v_template", "shapedirs", "posedirs", "J_regressor", "weights"):
        if not np.all(np.isfinite(arrays[key])):
            raise BodyModelFileError(f"{path}: array '{key}' holds NaN or infinite values")
    return arrays


def write_model_file(path: str | os.PathLike, arrays: dict[str, np.ndarray],
                     compress: bool = True) -> Path:
    """Write ``arrays`` as an ``.npz`` atomically (compressed by default); returns the path.

    The root parent in ``kintree_table`` is written as 2**32-1 (uint32), as in official files.
    """
    path = Path(path)
    out = {k: np.asarray(v) for k, v in arrays.items()}
    if "kintree_table" in out:
        kin = out["kintree_table"].astype(np.int64)
        kin[kin < 0] = ROOT_PARENT_OFFICIAL
        out["kintree_table"] = kin.astype(np.uint32)
    for key, arr in out.items():
        if arr.dtype == object:
            raise ValueError(f"array '{key}' has dtype object; only plain arrays can be written")
    with atomic_path(path, suffix=".npz") as tmp:
        with open(tmp, "wb") as fh:
            (np.savez_compressed if compress else np.savez)(fh, **out)
    return path
