"""Shared assets of the body tests: the proxy model's arrays (the model file is written once in
tests/conftest.py) and a small fake model in the official SMPL-X layout."""

from __future__ import annotations

import numpy as np
import pytest

from signsplat.body.joints import NUM_JOINTS, SMPLX_PARENTS


@pytest.fixture(scope="session")
def proxy_arrays(proxy_body_path):
    from signsplat.body.model_file import load_model_arrays

    return load_model_arrays(proxy_body_path)


def fake_official_arrays(num_vertices: int = 330, num_dirs: int = 20, seed: int = 0) -> dict:
    """A small random model in the official SMPL-X .npz layout (as in SMPLX_NEUTRAL.npz)."""
    rng = np.random.default_rng(seed)
    per = num_vertices // NUM_JOINTS
    V = per * NUM_JOINTS
    centres = np.cumsum(rng.normal(0, 0.1, (NUM_JOINTS, 3)), axis=0)
    verts = np.repeat(centres, per, axis=0) + rng.normal(0, 0.02, (V, 3))
    owner = np.repeat(np.arange(NUM_JOINTS), per)
    weights = rng.uniform(0, 0.2, (V, NUM_JOINTS))
    weights[np.arange(V), owner] += 1.0
    weights /= weights.sum(1, keepdims=True)
    J_reg = np.zeros((NUM_JOINTS, V))
    J_reg[owner, np.arange(V)] = 1.0 / per
    faces = rng.integers(0, V, (2 * V, 3))
    kintree = np.stack([np.array(SMPLX_PARENTS, np.int64), np.arange(NUM_JOINTS)])
    kintree[0, 0] = 2**32 - 1
    q = np.linalg.qr(rng.normal(size=(45, 45)))[0]
    return {
        "v_template": verts, "f": faces.astype(np.uint32),
        "shapedirs": rng.normal(0, 0.01, (V, 3, num_dirs)),
        "posedirs": rng.normal(0, 0.001, (V, 3, 486)),
        "J_regressor": J_reg, "weights": weights, "kintree_table": kintree,
        "hands_componentsl": q, "hands_componentsr": q.T.copy(),
        "hands_meanl": rng.normal(0, 0.1, 45), "hands_meanr": rng.normal(0, 0.1, 45),
        "lmk_faces_idx": rng.integers(0, len(faces), 51).astype(np.uint32),
        "lmk_bary_coords": np.full((51, 3), 1.0 / 3.0),
        "dynamic_lmk_faces_idx": rng.integers(0, len(faces), (79, 17)),
        "dynamic_lmk_bary_coords": np.full((79, 17, 3), 1.0 / 3.0),
        "joint2num": np.arange(NUM_JOINTS), "vt": rng.uniform(0, 1, (V, 2)),
        "ft": faces.astype(np.uint32),
    }


@pytest.fixture
def make_fake_arrays():
    """The factory :func:`fake_official_arrays` (tests modify its arrays)."""
    return fake_official_arrays


@pytest.fixture
def fake_path(tmp_path):
    path = tmp_path / "SMPLX_FAKE.npz"
    np.savez(path, **fake_official_arrays())
    return path
