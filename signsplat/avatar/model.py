"""The SignSplat avatar: Gaussians anchored on the (upsampled) SMPL-X mesh (paper 3.2-3.5).

Each point p is a barycentric combination of three mesh vertices plus an offset ``l`` along
the normal of the face it lies on (only points added by densification learn their
combination ``k = softmax(logits)`` and ``l``; mesh points keep theirs fixed). Original
vertices are displaced along their normals, ``v' = v + d * n_v`` (eq. 3), with ``d`` predicted
by a light 1D-convolutional network and bounded per part (body > head > hands).

Posing uses the body model's own output: canonical vertices ``v_shaped`` (betas and
expression applied) and posed vertices ``vertices``; the displacement is carried to the posed
space by each vertex's blended LBS matrix ``M_v = sum_j w_vj R_j`` (exact for LBS). Gaussian
rotations are the canonical ones turned by the rotation of their anchors' blended LBS frames
(orthonormalised per vertex, blended as quaternions).

Gaussian attributes are canonical learnable tensors; when ``pose_dependent`` is on, a shared
1D-conv network Omega over a sequence ordered along a Morton curve (so that sequence
neighbours are spatial neighbours) takes the canonical position and its translation to the
posed one (in the body's root frame) and four zero-initialised heads add pose-dependent
residuals to scale, rotation, opacity and colour. The paper runs Omega over the points
(``pose_net_on: points``); by default it runs over the mesh vertices and its residuals reach
the points by their barycentric weights, like the displacement (``vertices``: a ninth of the
work at 90k points). Scales pass through a sigmoid bounded per part. Quaternions are stored
``(w, x, y, z)`` as in gsplat and the 3DGS PLY format.

Everything that is a function of the vertices (posed positions, LBS rotations, Omega on
vertices, the shading gain) is computed per vertex and carried to the points in one
barycentric interpolation (:mod:`signsplat.avatar.interp`); the per-point attributes are one
fused step (:mod:`signsplat.avatar.attributes`).

Shading (switch ``shading``, an addition to the paper): a studio light makes a point darker or
brighter as the body turns, which a colour fixed per point cannot follow and Omega (whose input
is positions) learns only slowly. One learnable global irradiance, a 9-coefficient (order-2)
real spherical-harmonics function of the posed unit normal per colour channel (the classic
irradiance-environment-map approximation of Lambertian lighting, Ramamoorthi and Hanrahan
2001), multiplies every point's colour: ``rgb' = gain(n) * rgb``. It starts at gain 1 and costs
27 parameters. The gain is evaluated at the vertex normals of the posed mesh and interpolated
to the points (no gradient flows into the geometry through the normals).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import nn

from signsplat.avatar.config import ModelConfig
from signsplat.avatar.attributes import SH_C0, point_attributes
from signsplat.avatar.interp import barycentric
from signsplat.avatar.upsample import PointAnchors
from signsplat.geometry.mesh import face_normals, vertex_normals

# part label (joints.PART_*: body, head, left hand, right hand) -> index into (body, head, hands)
_PART_TO_GROUP = torch.tensor([0, 1, 2, 2])

# per-point tensors (resized together by densification / pruning / checkpoint loading)
POINT_PARAMS = ("scale_raw", "quat", "opacity_raw", "sh_dc", "sh_rest", "bary_logits",
                "normal_offset")
POINT_BUFFERS = ("anchors", "bary_fixed", "face", "is_original", "learnable", "part")


def num_sh_bases(degree: int) -> int:
    return (degree + 1) ** 2


def irradiance_basis(n: torch.Tensor) -> torch.Tensor:
    """Real spherical harmonics up to order 2 of (..., 3) unit vectors -> (..., 9)."""
    x, y, z = n.unbind(-1)
    return torch.stack([
        torch.full_like(x, 0.28209479177387814),
        0.4886025119029199 * y, 0.4886025119029199 * z, 0.4886025119029199 * x,
        1.0925484305920792 * x * y, 1.0925484305920792 * y * z,
        0.31539156525252005 * (3.0 * z * z - 1.0),
        1.0925484305920792 * x * z, 0.5462742152960396 * (x * x - y * y),
    ], -1)


def wxyz_to_xyzw(q: torch.Tensor) -> torch.Tensor:
    return torch.cat([q[..., 1:], q[..., :1]], -1)


def xyzw_to_wxyz(q: torch.Tensor) -> torch.Tensor:
    return torch.cat([q[..., 3:], q[..., :3]], -1)


def frame_quats(m: torch.Tensor, eps: float = 1e-6) -> torch.Tensor:
    """(..., 4) wxyz unit quaternions of the rotations of (..., 3, 3) frames ``m`` (the blended
    LBS matrices): the first two columns of ``m + eps I`` orthonormalised (Gram-Schmidt, as
    ``roma.special_gramschmidt``), then Markley's variant of Shepperd's method (as
    ``roma.rotmat_to_unitquat``: the largest of the four candidates ``4 q_i q``, normalised).

    The same values as the roma composition, computed on contiguous per-component vectors:
    on the avatar's (3, 10475) frames roma's batched 3 x 3 operations on strided views cost
    about 0.1 s forward and backward (docs/avatar_step.md), these a few milliseconds.
    """
    shape = m.shape[:-2]
    c = m.reshape(-1, 9).T.contiguous()  # (9, N): row 3 i + j is m[..., i, j]
    x0, x1, x2 = c[0] + eps, c[3], c[6]
    y0, y1, y2 = c[1], c[4] + eps, c[7]
    xn = torch.sqrt(x0 * x0 + x1 * x1 + x2 * x2)
    x0, x1, x2 = x0 / xn, x1 / xn, x2 / xn
    d = x0 * y0 + x1 * y1 + x2 * y2
    y0, y1, y2 = y0 - d * x0, y1 - d * x1, y2 - d * x2
    yn = torch.sqrt(y0 * y0 + y1 * y1 + y2 * y2)
    y0, y1, y2 = y0 / yn, y1 / yn, y2 / yn
    z0, z1, z2 = x1 * y2 - x2 * y1, x2 * y0 - x0 * y2, x0 * y1 - x1 * y0
    # Markley's A = R^T with R = [x y z] (columns): a_ij = R_ji
    a11, a12, a13, a21, a22, a23, a31, a32, a33 = x0, x1, x2, y0, y1, y2, z0, z1, z2
    cand = (  # x^(i) = 4 q_i q in (x, y, z, w)
        (1 + a11 - a22 - a33, a12 + a21, a13 + a31, a23 - a32),
        (a21 + a12, 1 + a22 - a33 - a11, a23 + a32, a31 - a13),
        (a31 + a13, a32 + a23, 1 + a33 - a11 - a22, a12 - a21),
        (a23 - a32, a31 - a13, a12 - a21, 1 + a11 + a22 + a33),
    )
    with torch.no_grad():  # one-hot of the largest diagonal entry (the first of equals)
        diag = [cand[i][i] for i in range(4)]
        top = torch.maximum(torch.maximum(diag[0], diag[1]), torch.maximum(diag[2], diag[3]))
        taken = torch.zeros_like(top, dtype=torch.bool)
        pick = []
        for i in range(4):
            hit = (diag[i] == top) & ~taken
            taken |= hit
            pick.append(hit.to(m.dtype))
    # products with 0/1 masks rather than torch.where or a gather: on (N,) vectors both were
    # many times slower here, forward and backward
    q = [sum(pick[i] * cand[i][comp] for i in range(4)) for comp in (3, 0, 1, 2)]  # w x y z
    norm = torch.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    return (torch.stack(q, -1) / norm[:, None]).reshape(*shape, 4)


def morton_order(points: torch.Tensor, bits: int = 10) -> torch.Tensor:
    """Permutation (P,) sorting (P, 3) points along a Z-order curve (spatial locality)."""
    lo, hi = points.min(0).values, points.max(0).values
    q = ((points - lo) / (hi - lo).clamp_min(1e-9) * (2**bits - 1)).long()
    code = torch.zeros(len(points), dtype=torch.long)
    for b in range(bits):
        for axis in range(3):
            code |= ((q[:, axis] >> b) & 1) << (3 * b + axis)
    return torch.argsort(code, stable=True)


def _tanh_ratio(norm: torch.Tensor) -> torch.Tensor:
    """``tanh(n) / n``, 1 at ``n = 0`` (its series below 1e-3). ``raw * bound * tanh_ratio(|raw|)``
    bounds a vector's length by ``bound`` with slope ``bound`` at zero, where the zero-initialised
    head starts: written as ``tanh(n) / max(n, eps)`` the map is 0 there with a zero gradient,
    and the network never leaves zero."""
    small = norm < 1e-3
    return torch.where(small, 1 - norm ** 2 / 3, torch.tanh(norm) / norm.clamp_min(1e-3))


class ConvNet1d(nn.Module):
    """Light 1D-conv network over a point sequence.

    ``forward(x)`` maps (B, C_in, P) to a list of (B, P, C_k) heads: a trunk of ``layers``
    convolutions (``kernel`` wide, SiLU) and one zero-initialised linear layer whose outputs are
    split into the heads (so residual heads start at zero: the canonical model).
    """

    def __init__(self, c_in: int, hidden: int, heads: tuple[int, ...], kernel: int, layers: int):
        super().__init__()
        mods: list[nn.Module] = []
        c = c_in
        for _ in range(layers):
            mods += [nn.Conv1d(c, hidden, kernel, padding=kernel // 2), nn.SiLU()]
            c = hidden
        self.trunk = nn.Sequential(*mods)
        self.sizes = tuple(heads)
        self.head = nn.Linear(hidden, sum(heads))
        nn.init.zeros_(self.head.weight)
        nn.init.zeros_(self.head.bias)

    def forward(self, x: torch.Tensor) -> list[torch.Tensor]:
        f = self.trunk(x)  # (B, hidden, P)
        # the linear head applied as a 1x1 convolution in the trunk's layout, then transposed:
        # transposing the trunk's output instead hands its last SiLU a gradient laid out
        # unlike its input, whose backward then takes a strided path several times slower
        out = F.conv1d(f, self.head.weight[:, :, None], self.head.bias).transpose(1, 2)
        return list(torch.split(out, self.sizes, dim=-1))


@dataclass
class PosedGaussians:
    """Gaussians of B frames over P points (float32, metres).

    means (B,P,3), quats (B,P,4) wxyz unit, scales (B,P,3) > 0, opacities (B,P) in (0,1),
    colors (B,P,K,3) SH coefficients with K = (sh_degree+1)^2,
    displacement (V,3) or None (eq. 3 d, before the normal product),
    normal_offset (P,) the l of each point (0 where fixed).
    """

    means: torch.Tensor
    quats: torch.Tensor
    scales: torch.Tensor
    opacities: torch.Tensor
    colors: torch.Tensor
    displacement: torch.Tensor | None
    normal_offset: torch.Tensor
    sh_degree: int


def _quat_from_z(n: torch.Tensor) -> torch.Tensor:
    """(P, 4) xyzw unit quaternions of the shortest rotations taking +z to the (P, 3) vectors
    ``n`` (identity where ``n`` is zero; the half-turn about x where ``n`` points along -z)."""
    n = n / n.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    w = 1.0 + n[:, 2]
    q = torch.stack([-n[:, 1], n[:, 0], torch.zeros_like(w), w], -1)  # z x n, 1 + z.n
    flip = w < 1e-6
    q[flip] = torch.tensor([1.0, 0.0, 0.0, 0.0])
    zero = n.norm(dim=-1) < 0.5
    q[zero] = torch.tensor([0.0, 0.0, 0.0, 1.0])
    return q / q.norm(dim=-1, keepdim=True)


def _logit(p: torch.Tensor) -> torch.Tensor:
    p = p.clamp(1e-4, 1 - 1e-4)
    return torch.log(p) - torch.log1p(-p)


class AvatarModel(nn.Module):
    """Mesh-anchored Gaussian avatar. Shapes: V vertices, F faces, J joints, P points.

    Args:
        points: anchored points from :func:`signsplat.avatar.upsample.upsample_mesh`.
        faces: (F, 3) int64 mesh faces; lbs_weights: (V, J) float skinning weights;
        template: (V, 3) canonical vertices (for initial scales and input normalisation);
        cfg: :class:`ModelConfig`.
    """

    def __init__(self, points: PointAnchors, faces: torch.Tensor, lbs_weights: torch.Tensor,
                 template: torch.Tensor, cfg: ModelConfig):
        super().__init__()
        self.cfg = cfg
        n = len(points)
        n_v = int(lbs_weights.shape[0])
        self.num_vertices = n_v
        self.register_buffer("faces", faces.long().clone())
        self.register_buffer("lbs_weights", lbs_weights.float().clone())
        self.register_buffer("template", template.float().clone())
        center = template.mean(0)
        self.register_buffer("center", center.float())
        self.register_buffer("extent", (template - center).abs().max().float().reshape(1))
        self.register_buffer("scale_bounds", torch.tensor(
            [cfg.scale_max.body, cfg.scale_max.head, cfg.scale_max.hands], dtype=torch.float32))
        self.register_buffer("disp_bounds", torch.tensor(
            [cfg.displacement_limit.body, cfg.displacement_limit.head,
             cfg.displacement_limit.hands], dtype=torch.float32))
        # per-point buffers
        self.register_buffer("anchors", points.anchors.clone())
        self.register_buffer("bary_fixed", points.bary.clone())
        self.register_buffer("face", points.face.clone())
        self.register_buffer("is_original", points.is_original.clone())
        self.register_buffer("learnable", torch.zeros(n, dtype=torch.bool))
        self.register_buffer("part", points.part.clone())

        # canonical Gaussian parameters
        pos = points.positions(self.template)
        init_scale = self._spacing(pos)
        smax = self.scale_max_per_point()
        frac = ((init_scale - cfg.scale_min) / (smax - cfg.scale_min)).clamp(0.02, 0.9)
        k = num_sh_bases(cfg.sh_degree)
        color = torch.tensor(cfg.init_color, dtype=torch.float32)
        raw = _logit(frac)[:, None].repeat(1, 3)
        if cfg.flat_init > 0:
            # discs in the surface: local z along the canonical normal, thin along it
            normal = (vertex_normals(self.template[None], self.faces)[0][points.anchors]
                      * points.bary[..., None]).sum(1)
            quat = xyzw_to_wxyz(_quat_from_z(normal))
            raw[:, 2] = _logit(frac * cfg.flat_init)
        else:
            quat = torch.tensor([1.0, 0.0, 0.0, 0.0]).repeat(n, 1)
        self.scale_raw = nn.Parameter(raw)
        self.quat = nn.Parameter(quat)
        self.opacity_raw = nn.Parameter(_logit(torch.full((n, 1), cfg.init_opacity)))
        self.sh_dc = nn.Parameter(((color - 0.5) / SH_C0).repeat(n, 1, 1))
        self.sh_rest = nn.Parameter(torch.zeros(n, k - 1, 3))
        self.bary_logits = nn.Parameter(torch.zeros(n, 3))
        self.normal_offset = nn.Parameter(torch.zeros(n, 1))

        self.omega = (ConvNet1d(6, cfg.hidden, (3, 4, 1, 3), cfg.kernel, cfg.layers)
                      if cfg.pose_dependent else None)
        self.disp_net = (ConvNet1d(3, cfg.hidden, (3,), cfg.kernel, cfg.layers)
                         if cfg.displacement else None)
        if cfg.shading:
            coeffs = torch.zeros(9, 3)
            coeffs[0] = 1.0 / 0.28209479177387814  # gain 1 everywhere
            self.irradiance = nn.Parameter(coeffs)
        else:
            self.irradiance = None
        self.register_buffer("vertex_order", morton_order(self.template))
        self.register_buffer("point_order", morton_order(pos))

    # ------------------------------------------------------------------ helpers
    @property
    def num_points(self) -> int:
        return int(self.anchors.shape[0])

    def _spacing(self, pos: torch.Tensor, k: int = 4) -> torch.Tensor:
        """Mean distance (P,) to the k nearest other points (initial Gaussian size)."""
        from scipy.spatial import cKDTree

        tree = cKDTree(pos.detach().cpu().numpy())
        d, _ = tree.query(pos.detach().cpu().numpy(), k=k + 1)
        return torch.as_tensor(d[:, 1:].mean(1), dtype=torch.float32) * 0.5

    def part_group(self) -> torch.Tensor:
        """(P,) 0 body, 1 head, 2 hands."""
        return _PART_TO_GROUP.to(self.part.device)[self.part]

    def scale_max_per_point(self) -> torch.Tensor:
        return self.scale_bounds[self.part_group()]

    def barycentric(self) -> torch.Tensor:
        """(P, 3) current barycentric weights (learnable only for densified points)."""
        idx = torch.nonzero(self.learnable)[:, 0]
        if len(idx) == 0:
            return self.bary_fixed
        return self.bary_fixed.index_put((idx,), torch.softmax(self.bary_logits[idx], -1))

    def offsets(self) -> torch.Tensor:
        """(P,) normal offsets l (zero where not learnable)."""
        return torch.where(self.learnable, self.normal_offset[:, 0],
                           torch.zeros_like(self.normal_offset[:, 0]))

    def canonical_points(self) -> torch.Tensor:
        """(P, 3) rest-pose template positions of the points (no displacement, no offset)."""
        return (self.template[self.anchors] * self.barycentric().detach()[..., None]).sum(1)

    def refresh_order(self) -> None:
        """Recompute the Morton order of the points (after densification or pruning)."""
        self.point_order = morton_order(self.canonical_points().cpu()).to(self.anchors.device)

    def displacement(self) -> torch.Tensor | None:
        """(V, 3) eq. 3 displacement vectors d, |d| bounded per part; None when switched off."""
        if self.disp_net is None:
            return None
        # d depends on the weights only (not on the pose): without autograd (rendering a
        # sequence) it is computed once and reused until a weight changes
        key = tuple(p._version for p in self.disp_net.parameters()) + (
            tuple(id(p) for p in self.disp_net.parameters()),)
        cached = getattr(self, "_disp_cache", None)
        if not torch.is_grad_enabled() and cached is not None and cached[0] == key:
            return cached[1]
        d = self._displacement()
        self._disp_cache = (key, d) if not torch.is_grad_enabled() else None
        return d

    def _displacement(self) -> torch.Tensor:
        order = self.vertex_order
        x = ((self.template - self.center) / self.extent)[order].T[None]
        raw = self.disp_net(x)[0][0]  # (V, 3) in sequence order
        raw = torch.empty_like(raw).index_copy(0, order, raw)
        v_parts = _PART_TO_GROUP.to(self.part.device)[self.part[: self.num_vertices]]
        bound = self.disp_bounds[v_parts][:, None]
        return raw * (bound * _tanh_ratio(raw.norm(dim=-1, keepdim=True)))

    # ------------------------------------------------------------------ forward
    def forward(self, v_shaped: torch.Tensor, vertices: torch.Tensor, transforms: torch.Tensor,
                transl: torch.Tensor | None, sh_degree: int) -> PosedGaussians:
        """Pose the Gaussians for B frames.

        v_shaped: (B, V, 3) canonical vertices; vertices: (B, V, 3) posed vertices;
        transforms: (B, J, 4, 4) LBS joint transforms (index 0 = root); transl: (B, 3) or None;
        sh_degree: SH degree in use (coefficients above it are dropped).

        Whatever is a function of the vertices (the blended LBS frames, the displacement, the
        pose network when ``model.pose_net_on`` is ``vertices``, the shading gain) is computed
        per vertex and carried to the points in one barycentric interpolation.
        """
        rot = transforms[..., :3, :3]
        m_v = torch.einsum("vj,bjxy->bvxy", self.lbs_weights, rot)  # (B, V, 3, 3)
        disp = self.displacement()
        if disp is not None:
            off = disp[None] * vertex_normals(v_shaped, self.faces)
            v_c = v_shaped + off
            v_p = vertices + (m_v @ off[..., None])[..., 0]
        else:
            v_c, v_p = v_shaped, vertices
        # the rotation of each vertex's blended LBS frame; blended over each point's anchors on
        # the hemisphere of its first anchor's (first in the fields: align) and normalised with
        # the attributes
        q_v = frame_quats(m_v)
        fields = {"q": q_v, "x_p": v_p}
        point_net = self.omega is not None and self.cfg.pose_net_on == "points"
        if point_net:
            fields["x_c"] = v_c
        elif self.omega is not None:
            fields["heads"] = self._pose_net_vertices(v_c, v_p, transforms, transl)
        if self.irradiance is not None:
            # the gain of each vertex's posed normal, interpolated (no gradient into the
            # geometry through the normals)
            with torch.no_grad():
                basis = irradiance_basis(vertex_normals(v_p.detach(), self.faces))  # (B, V, 9)
            # elementwise product + sum rather than a matmul: BLAS's reduction for the
            # coefficients' gradient is not reproducible run to run, this is
            fields["gain"] = (basis[..., None] * self.irradiance).sum(-2)
        bary = self.barycentric()
        f = dict(zip(fields, barycentric(torch.cat(list(fields.values()), -1), self.anchors, bary,
                                         align=True).split([x.shape[-1]
                                                            for x in fields.values()], -1)))
        l_off = self.offsets()
        on_face = self.learnable & (self.face >= 0)
        if bool(on_face.any()):
            idx = torch.nonzero(on_face)[:, 0]
            fidx = self.face[idx]
            for x, v in (("x_p", v_p), ("x_c", v_c)):
                if x not in f:
                    continue
                if len(idx) > len(self.faces):  # every face once, then per point
                    n = face_normals(v, self.faces).index_select(1, fidx)
                else:
                    n = face_normals(v, self.faces[fidx])
                f[x] = f[x].index_add(1, idx, n * l_off[idx, None])
        heads = f.get("heads")
        if point_net:
            heads = self._pose_net_points(f["x_c"], f["x_p"], transforms, transl)
        k = num_sh_bases(sh_degree)
        scales, quats, opacities, colors = point_attributes(
            self.scale_raw, self.quat, self.opacity_raw[:, 0], self.sh_dc[:, 0],
            self.sh_rest[:, : k - 1], heads, f.get("gain"), f["q"], self.scale_max_per_point(),
            self.cfg.scale_min)
        return PosedGaussians(means=f["x_p"], quats=quats, scales=scales, opacities=opacities,
                              colors=colors, displacement=disp, normal_offset=l_off,
                              sh_degree=sh_degree)

    def _root_frame(self, x_p: torch.Tensor, transforms: torch.Tensor,
                    transl: torch.Tensor | None) -> torch.Tensor:
        """(B, N, 3) posed positions in the body's root frame (translation removed)."""
        b = x_p.shape[0]
        root = transforms[:, 0]
        tr = transl if transl is not None else torch.zeros(b, 3, dtype=x_p.dtype,
                                                           device=x_p.device)
        return torch.einsum("byx,bpy->bpx", root[:, :3, :3],
                            x_p - tr[:, None] - root[:, None, :3, 3])

    def _pose_net_vertices(self, v_c: torch.Tensor, v_p: torch.Tensor,
                           transforms: torch.Tensor, transl: torch.Tensor | None) -> torch.Tensor:
        """Omega over the vertex sequence: (B, V, 11) residuals (scale 3, rotation 4, opacity 1,
        colour 3) from each vertex's canonical position and its translation to the posed one."""
        feat = torch.cat([(v_c - self.center) / self.extent,
                          (self._root_frame(v_p, transforms, transl) - v_c) / self.extent], -1)
        order = self.vertex_order
        out = torch.cat(self.omega(feat[:, order].transpose(1, 2)), -1)  # sequence order
        return torch.empty_like(out).index_copy(1, order, out)

    def _pose_net_points(self, x_c: torch.Tensor, x_p: torch.Tensor, transforms: torch.Tensor,
                         transl: torch.Tensor | None) -> torch.Tensor:
        """Omega over the point sequence (the paper's): (B, P, 11) residuals."""
        feat = torch.cat([(x_c - self.center) / self.extent,
                          (self._root_frame(x_p, transforms, transl) - x_c) / self.extent], -1)
        order = self.point_order
        out = torch.cat(self.omega(feat[:, order].transpose(1, 2)), -1)  # sequence order
        return torch.empty_like(out).index_copy(1, order, out)

    # ------------------------------------------------------------------ resizing
    def point_tensors(self) -> dict[str, torch.Tensor]:
        """Every per-point parameter and buffer by name (first dimension P)."""
        return {name: getattr(self, name) for name in POINT_PARAMS + POINT_BUFFERS}

    def resize_like(self, state: dict[str, torch.Tensor]) -> None:
        """Give per-point tensors the sizes in ``state`` (before ``load_state_dict``)."""
        for name in POINT_PARAMS:
            setattr(self, name, nn.Parameter(torch.empty_like(state[name])))
        for name in POINT_BUFFERS + ("point_order",):
            setattr(self, name, torch.empty_like(state[name]))


def sh_degree_at(step: int, iterations: int, max_degree: int, rise_at: float) -> int:
    """SH degree schedule: 0 for most of training, ``max_degree`` after ``rise_at`` of it."""
    if max_degree == 0 or iterations <= 0:
        return 0
    if step < math.floor(rise_at * iterations):
        return 0
    return max_degree
