"""Canonical mesh upsampling (paper 3.2): points at the centres of large faces and along long edges.

With ``interior="grid"`` a large face gets, instead of its centre alone, every interior point of
a barycentric grid whose step is the face's longest edge divided by ``n = ceil(longest /
edge_length)`` (the centre is the grid's only interior point when n = 3): on a coarse mesh the
inside of a big triangle is then as densely covered as its edges, which texture needs.

Every point of the avatar is a barycentric combination of three original mesh vertices
(``anchors``), so it follows the body model exactly: original vertices are ``(v, v, v)`` with
weights ``(1, 0, 0)``; a point on an edge ``(a, b)`` is ``(a, b, a)`` with ``(1 - t, t, 0)``; a
face centre is ``(a, b, c)`` with ``(1/3, 1/3, 1/3)``. Skinning weights and part labels of new
points are interpolated from the anchors (weights linearly, labels from the heaviest anchor).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch


@dataclass
class PointAnchors:
    """Points anchored on a triangle mesh; P points over a mesh of V vertices and F faces.

    anchors: (P, 3) int64 vertex indices; bary: (P, 3) float32 barycentric weights (sum 1);
    face: (P,) int64 index of the face the point lies on (-1 for original vertices);
    is_original: (P,) bool, True for the V original vertices (always the first V points);
    part: (P,) int64 part label (``signsplat.body.joints.PART_*``).
    """

    anchors: torch.Tensor
    bary: torch.Tensor
    face: torch.Tensor
    is_original: torch.Tensor
    part: torch.Tensor

    def __len__(self) -> int:
        return int(self.anchors.shape[0])

    def weights(self, lbs_weights: torch.Tensor) -> torch.Tensor:
        """(P, J) skinning weights interpolated from the vertices' (V, J) weights."""
        return (lbs_weights[self.anchors] * self.bary[..., None]).sum(1)

    def positions(self, vertices: torch.Tensor) -> torch.Tensor:
        """(..., P, 3) point positions from (..., V, 3) vertex positions."""
        return (vertices[..., self.anchors, :] * self.bary[..., None]).sum(-2)


def _unique_edges(faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unique undirected edges (E, 2) and, for each, one face that contains it (E,)."""
    e = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    owner = np.tile(np.arange(len(faces)), 3)
    e = np.sort(e, axis=1)
    edges, first = np.unique(e, axis=0, return_index=True)
    return edges, owner[first]


def upsample_mesh(vertices: np.ndarray | torch.Tensor, faces: np.ndarray | torch.Tensor,
                  part_labels: np.ndarray | torch.Tensor, edge_length: float,
                  face_area: float, interior: str = "centre") -> PointAnchors:
    """Anchored points of the upsampled canonical mesh.

    vertices: (V, 3) canonical positions in metres; faces: (F, 3) int; part_labels: (V,) int.
    An edge of length L > ``edge_length`` gets ``ceil(L / edge_length) - 1`` evenly spaced
    points; a face of area > ``face_area`` (m^2) gets its centroid. Returns the V original
    vertices first, then edge points, then face centres.
    """
    v = np.asarray(vertices.detach().cpu() if torch.is_tensor(vertices) else vertices,
                   dtype=np.float64)
    f = np.asarray(faces.cpu() if torch.is_tensor(faces) else faces, dtype=np.int64)
    parts = np.asarray(part_labels.cpu() if torch.is_tensor(part_labels) else part_labels,
                       dtype=np.int64)
    n_v = len(v)
    anchors = [np.stack([np.arange(n_v)] * 3, 1)]
    bary = [np.tile([1.0, 0.0, 0.0], (n_v, 1))]
    face_ix = [np.full(n_v, -1)]

    edges, owner = _unique_edges(f)
    lengths = np.linalg.norm(v[edges[:, 0]] - v[edges[:, 1]], axis=1)
    counts = np.maximum(np.ceil(lengths / edge_length).astype(np.int64) - 1, 0)
    if counts.sum():
        e_rep = np.repeat(np.arange(len(edges)), counts)
        # k-th of n points on the edge sits at t = k / (n + 1)
        k = np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts) + 1
        t = k / (counts[e_rep] + 1)
        a, b = edges[e_rep, 0], edges[e_rep, 1]
        anchors.append(np.stack([a, b, a], 1))
        bary.append(np.stack([1 - t, t, np.zeros_like(t)], 1))
        face_ix.append(owner[e_rep])

    tri = v[f]
    areas = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
    big = np.nonzero(areas > face_area)[0]
    if interior not in ("centre", "grid"):
        raise ValueError(f"interior must be 'centre' or 'grid', got {interior!r}")
    if interior == "grid" and len(big):
        longest = np.linalg.norm(tri[big] - tri[big][:, [1, 2, 0]], axis=2).max(1)
        n = np.maximum(np.ceil(longest / edge_length).astype(np.int64), 3)
        for m in np.unique(n):
            sel = big[n == m]
            ij = np.array([(i, j, m - i - j) for i in range(1, m) for j in range(1, m - i)
                           if m - i - j >= 1], dtype=np.float64) / m  # (Q, 3) interior grid
            anchors.append(np.repeat(f[sel], len(ij), 0))
            bary.append(np.tile(ij, (len(sel), 1)))
            face_ix.append(np.repeat(sel, len(ij)))
    elif len(big):
        anchors.append(f[big])
        bary.append(np.full((len(big), 3), 1.0 / 3.0))
        face_ix.append(big)

    anchors_a = np.concatenate(anchors)
    bary_a = np.concatenate(bary)
    heaviest = anchors_a[np.arange(len(anchors_a)), bary_a.argmax(1)]
    return PointAnchors(
        anchors=torch.as_tensor(anchors_a, dtype=torch.long),
        bary=torch.as_tensor(bary_a, dtype=torch.float32),
        face=torch.as_tensor(np.concatenate(face_ix), dtype=torch.long),
        is_original=torch.arange(len(anchors_a)) < n_v,
        part=torch.as_tensor(parts[heaviest], dtype=torch.long),
    )
