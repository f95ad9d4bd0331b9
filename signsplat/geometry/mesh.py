"""Triangle-mesh normals (torch), shared by the avatar and the fit's silhouette terms."""

from __future__ import annotations

import torch


def face_normals(vertices: torch.Tensor, faces: torch.Tensor, eps: float = 1e-12) -> torch.Tensor:
    """Unit normals (..., F, 3) of the faces (F, 3) of (..., V, 3) vertices (zero if degenerate)."""
    tri = vertices[..., faces, :]
    n = torch.cross(tri[..., 1, :] - tri[..., 0, :], tri[..., 2, :] - tri[..., 0, :], dim=-1)
    return n / n.norm(dim=-1, keepdim=True).clamp_min(eps)


def vertex_normals(vertices: torch.Tensor, faces: torch.Tensor) -> torch.Tensor:
    """Area-weighted unit vertex normals (B, V, 3) of (B, V, 3) vertices (zero for a vertex
    whose faces are all degenerate or that no face uses)."""
    tri = vertices[:, faces]  # (B, F, 3, 3)
    fn = torch.cross(tri[:, :, 1] - tri[:, :, 0], tri[:, :, 2] - tri[:, :, 0], dim=-1)
    b, f = fn.shape[:2]
    # one scatter along the first dimension, faster than three along dim 1; corner 0 of every
    # face, then 1, then 2, as three scatters would add them, so the sums are the same
    rows = fn.transpose(0, 1).reshape(f, b * 3).repeat(3, 1)
    vn = torch.zeros(vertices.shape[1], b * 3, dtype=fn.dtype, device=fn.device)
    vn = vn.index_add(0, faces.T.reshape(-1), rows).reshape(-1, b, 3).transpose(0, 1)
    return vn / vn.norm(dim=-1, keepdim=True).clamp_min(1e-12)
