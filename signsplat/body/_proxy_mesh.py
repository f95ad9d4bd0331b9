"""Signed-distance meshing of the proxy body (private to ``proxy``).

The body is a smooth union of primitives (round cones, ellipsoids, rounded boxes). The SDF is
evaluated block by block only where the surface passes, each block with only the primitives
that can reach it; marching cubes runs per block and vertices shared along block faces are
merged by the grid edge they lie on, which makes the result one closed surface. The dense
mesh is then decimated with quadric edge collapse (``fast_simplification``).
"""

from __future__ import annotations

import numpy as np

from signsplat.body._proxy_skeleton import Prim

BAND = 0.02  # SDF values are clipped to +-BAND (metres)


def prim_sdf(p: Prim, x: np.ndarray) -> np.ndarray:
    """Signed distance (approximate for ellipsoids) of points x (N, 3) to primitive p, (N,)."""
    a = np.asarray(p.a)
    if p.kind == "cone":
        b = np.asarray(p.b)
        ab = b - a
        L2 = float(ab @ ab)
        xa = x - a
        t = np.clip((xa @ ab) / L2, 0.0, 1.0)
        xa -= t[:, None] * ab
        return np.sqrt(np.einsum("ij,ij->i", xa, xa)) - (p.r1 + (p.r2 - p.r1) * t)
    if p.kind == "ell":
        r = np.asarray(p.b)
        q = (x - a) / r
        k0 = np.sqrt(np.einsum("ij,ij->i", q, q))
        q /= r
        k1 = np.sqrt(np.einsum("ij,ij->i", q, q))
        return k0 * (k0 - 1.0) / np.maximum(k1, 1e-12)
    if p.kind == "box":
        q = np.abs(x - a) - np.asarray(p.b)
        outside = np.linalg.norm(np.maximum(q, 0.0), axis=1)
        inside = np.minimum(q.max(axis=1), 0.0)
        return outside + inside - p.r1
    raise ValueError(f"unknown primitive kind {p.kind!r}")


def smin(a: np.ndarray, b: np.ndarray, k: float) -> np.ndarray:
    """Polynomial smooth minimum; equals min(a, b) exactly where |a - b| >= k."""
    if k <= 0.0:
        return np.minimum(a, b)
    h = np.maximum(k - np.abs(a - b), 0.0) / k
    return np.minimum(a, b) - h * h * k * 0.25


def body_sdf(prims: list[Prim], x: np.ndarray) -> np.ndarray:
    """SDF of the smooth union of ``prims`` (in order) at x (N, 3), clipped to +-BAND."""
    d = np.full(len(x), BAND)
    for p in prims:
        d = smin(d, prim_sdf(p, x), p.k)
    return np.clip(d, -BAND, BAND)


def _prim_boxes(prims: list[Prim]) -> tuple[np.ndarray, np.ndarray]:
    lo = np.array([p.bbox()[0] - (BAND + p.k + 1e-3) for p in prims])
    hi = np.array([p.bbox()[1] + (BAND + p.k + 1e-3) for p in prims])
    return lo, hi


def dense_mesh(prims: list[Prim], h: float = 0.002, block: int = 16,
               lo: np.ndarray | None = None, hi: np.ndarray | None = None):
    """Marching-cubes mesh (verts (N, 3) float64, faces (M, 3) int64) of the body at spacing h."""
    from skimage.measure import marching_cubes

    plo, phi = _prim_boxes(prims)
    lo = plo.min(axis=0) if lo is None else np.asarray(lo, float)
    hi = phi.max(axis=0) if hi is None else np.asarray(hi, float)
    nblocks = np.ceil((hi - lo) / (h * block)).astype(int)
    # coarse test at block centres: keep blocks the surface may cross
    idx = np.stack(np.meshgrid(*[np.arange(n) for n in nblocks], indexing="ij"), -1).reshape(-1, 3)
    centres = lo + (idx + 0.5) * h * block
    half_diag = 0.5 * np.sqrt(3.0) * h * block
    dc = np.full(len(centres), 1.0)
    for p in prims:  # unclipped union at the centres, to bound distances
        dc = smin(dc, prim_sdf(p, centres), p.k)
    keep = np.abs(dc) < 1.2 * half_diag + 0.003
    blo = lo + idx * h * block
    bhi = blo + h * block
    verts_all, faces_all, keys_all = [], [], []
    offset = 0
    eps = 1e-5
    for bi in np.nonzero(keep)[0]:
        overlap = np.all((plo <= bhi[bi]) & (phi >= blo[bi]), axis=1)
        if not overlap.any():
            continue
        sel = [prims[i] for i in np.nonzero(overlap)[0]]
        # node coordinates from the global index so shared nodes are bit-identical
        gi = idx[bi] * block
        gx = [lo[a] + (gi[a] + np.arange(block + 1)) * h for a in range(3)]
        g = np.stack(np.meshgrid(*gx, indexing="ij"), -1).reshape(-1, 3)
        vol = body_sdf(sel, g).reshape(block + 1, block + 1, block + 1)
        vol = np.where(np.abs(vol) < eps, np.where(vol < 0, -eps, eps), vol)
        if vol.min() > 0 or vol.max() < 0:
            continue
        v, f, _, _ = marching_cubes(vol, level=0.0, allow_degenerate=True)
        v = v.astype(np.float64) + gi  # global index coordinates
        # key = the grid edge a vertex lies on: (lower node, axis)
        frac = np.abs(v - np.round(v))
        axis = frac.argmax(axis=1)
        node = np.round(v).astype(np.int64)
        node[np.arange(len(v)), axis] = np.floor(v[np.arange(len(v)), axis]).astype(np.int64)
        keys_all.append(np.column_stack([node, axis]))
        verts_all.append(lo + v * h)
        faces_all.append(f.astype(np.int64) + offset)
        offset += len(v)
    verts = np.concatenate(verts_all)
    faces = np.concatenate(faces_all)
    keys = np.concatenate(keys_all)
    # pack (node i, j, k, axis) into one int64 (indices < 2**20)
    packed = ((keys[:, 0] * (1 << 20) + keys[:, 1]) * (1 << 20) + keys[:, 2]) * 4 + keys[:, 3]
    _, first, inverse = np.unique(packed, return_index=True, return_inverse=True)
    verts = verts[first]
    faces = inverse.reshape(-1)[faces]
    # drop faces made degenerate by the merge
    ok = (faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) & (faces[:, 0] != faces[:, 2])
    return verts, faces[ok]


def clean_mesh(verts: np.ndarray, faces: np.ndarray):
    """Remove unreferenced vertices and duplicate faces; returns (verts, faces)."""
    used = np.unique(faces)
    remap = np.full(len(verts), -1, dtype=np.int64)
    remap[used] = np.arange(len(used))
    faces = remap[faces]
    srt = np.sort(faces, axis=1)
    _, keep = np.unique(srt, axis=0, return_index=True)
    faces = faces[np.sort(keep)]
    return verts[used], faces


def project_to_surface(prims: list[Prim], x: np.ndarray, iters: int = 2) -> np.ndarray:
    """Move points onto the zero level of the body SDF (Newton steps along the gradient)."""
    eps = 1e-6
    x = x.copy()
    for _ in range(iters):
        f = body_sdf(prims, x)
        g = np.stack([(body_sdf(prims, x + e) - f) / eps for e in np.eye(3) * eps], axis=1)
        g2 = np.maximum((g * g).sum(axis=1), 1e-8)
        step = (f / g2)[:, None] * g
        # never move by more than 2 mm in one step
        n = np.linalg.norm(step, axis=1, keepdims=True)
        x -= step * np.minimum(1.0, 0.002 / np.maximum(n, 1e-12))
    return x


def decimate_regions(verts: np.ndarray, faces: np.ndarray, face_region: np.ndarray,
                     targets: dict[int, int], final_vertices: int):
    """Decimate each region to its own vertex budget, then the whole mesh to ``final_vertices``.

    face_region (F,) region id per face; targets: region id -> vertex count. Regions are
    decimated with their borders kept, so they stitch back exactly; a last global pass removes
    the dense border rings.
    """
    import fast_simplification

    parts_v, parts_f = [], []
    for reg, target in targets.items():
        f = faces[face_region == reg]
        used = np.unique(f)
        remap = np.full(len(verts), -1, dtype=np.int64)
        remap[used] = np.arange(len(used))
        v_sub, f_sub = verts[used], remap[f]
        v2, f2 = fast_simplification.simplify(v_sub, f_sub.astype(np.int32),
                                              target_count=max(2 * target, 4), agg=5.0,
                                              preserve_border=True)
        parts_v.append(np.asarray(v2, np.float64))
        parts_f.append(np.asarray(f2, np.int64))
    offs = np.cumsum([0] + [len(v) for v in parts_v])
    V = np.concatenate(parts_v)
    F = np.concatenate([f + o for f, o in zip(parts_f, offs[:-1])])
    _, first, inv = np.unique(V, axis=0, return_index=True, return_inverse=True)
    V, F = V[first], inv.reshape(-1)[F]
    V, F = clean_mesh(V, F)
    v3, f3 = fast_simplification.simplify(V, F.astype(np.int32),
                                          target_count=2 * final_vertices - 4, agg=5.0)
    return clean_mesh(np.asarray(v3, np.float64), np.asarray(f3, np.int64))
