"""The SignSplat avatar: Gaussians anchored on the (upsampled) SMPL-X mesh (paper 3.2-3.5).

Each point p is a barycentric combination of three mesh vertices plus an offset ``l`` along
the normal of the face it lies on (only points added by densification learn their
combination ``k = softmax(logits)`` and ``l``; mesh points keep theirs fixed). Original
vertices are displaced along their normals, ``v' = v + d * n_v`` (eq. 3), with ``d`` predicted
by a light 1D-convolutional network and bounded per part (body > head > hands).

Posing uses the body model's own output: canonical vertices ``v_shaped`` (betas and
expression applied) and posed vertices ``vertices``; the displacement is carried to the posed
space by each vertex's blended LBS matrix ``M_v = sum_j w_vj R_j`` (exact for LBS). Gaussian
rotations are the canonical ones turned by the orthonormalised blended matrix of their point.

Gaussian attributes are canonical learnable tensors; when ``pose_dependent`` is on, a shared
1D-conv network Omega over the point sequence (ordered along a Morton curve so that sequence
neighbours are spatial neighbours) takes the canonical point and its translation to the posed
point (in the body's root frame) and four zero-initialised heads add pose-dependent residuals to
scale, rotation, opacity and colour. Scales pass through a sigmoid bounded per part.
Quaternions are stored ``(w, x, y, z)`` as in gsplat and the 3DGS PLY format.

Shading (switch ``shading``, an addition to the paper): a studio light makes a point darker or
brighter as the body turns, which a colour fixed per point cannot follow and Omega (whose input
is positions) learns only slowly. One learnable global irradiance, a 9-coefficient (order-2)
real spherical-harmonics function of the posed unit normal per colour channel (the classic
irradiance-environment-map approximation of Lambertian lighting, Ramamoorthi and Hanrahan
2001), multiplies every point's colour: ``rgb' = gain(n) * rgb``. It starts at gain 1 and costs
27 parameters; normals are the bary-interpolated vertex normals of the posed mesh (no gradient
flows into the geometry through them).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import roma
import torch
from torch import nn

from signsplat.avatar.config import ModelConfig
from signsplat.avatar.upsample import PointAnchors
from signsplat.geometry.mesh import face_normals, vertex_normals

SH_C0 = 0.28209479177387814  # Y_0^0; gsplat colour = SH_C0 * f_dc + 0.5 (+ higher bands)

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


def shade_sh(sh: torch.Tensor, gain: torch.Tensor) -> torch.Tensor:
    """Multiply the RGB that SH coefficients (B, P, K, 3) decode to by ``gain`` (B, P, 3).

    The rasterizer decodes ``rgb = SH_C0 * dc + 0.5 + sum_k rest_k Y_k``; scaling it by g gives
    ``dc' = g * dc + (g - 1) * 0.5 / SH_C0`` and ``rest' = g * rest``.
    """
    dc = gain * sh[:, :, 0] + (gain - 1.0) * (0.5 / SH_C0)
    return torch.cat([dc[:, :, None], gain[:, :, None] * sh[:, :, 1:]], 2)


def wxyz_to_xyzw(q: torch.Tensor) -> torch.Tensor:
    return torch.cat([q[..., 1:], q[..., :1]], -1)


def xyzw_to_wxyz(q: torch.Tensor) -> torch.Tensor:
    return torch.cat([q[..., 3:], q[..., :3]], -1)


def morton_order(points: torch.Tensor, bits: int = 10) -> torch.Tensor:
    """Permutation (P,) sorting (P, 3) points along a Z-order curve (spatial locality)."""
    lo, hi = points.min(0).values, points.max(0).values
    q = ((points - lo) / (hi - lo).clamp_min(1e-9) * (2**bits - 1)).long()
    code = torch.zeros(len(points), dtype=torch.long)
    for b in range(bits):
        for axis in range(3):
            code |= ((q[:, axis] >> b) & 1) << (3 * b + axis)
    return torch.argsort(code, stable=True)


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
        f = self.trunk(x).transpose(1, 2)  # (B, P, hidden)
        return list(torch.split(self.head(f), self.sizes, dim=-1))


def quat_mul(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Hamilton product of (..., 4) quaternions in (w, x, y, z) order."""
    aw, ax, ay, az = a.unbind(-1)
    bw, bx, by, bz = b.unbind(-1)
    return torch.stack([aw * bw - ax * bx - ay * by - az * bz,
                        aw * bx + ax * bw + ay * bz - az * by,
                        aw * by - ax * bz + ay * bw + az * bx,
                        aw * bz + ax * by - ay * bx + az * bw], -1)


@dataclass
class PosedGaussians:
    """Gaussians of B frames over P points (float32, metres).

    means (B,P,3), quats (B,P,4) wxyz unit, scales (B,P,3) > 0, opacities (B,P) in (0,1),
    colors (B,P,K,3) SH coefficients with K = (sh_degree+1)^2, canonical (B,P,3) canonical
    positions, displacement (V,3) or None (eq. 3 d, before the normal product),
    normal_offset (P,) the l of each point (0 where fixed).
    """

    means: torch.Tensor
    quats: torch.Tensor
    scales: torch.Tensor
    opacities: torch.Tensor
    colors: torch.Tensor
    canonical: torch.Tensor
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
        soft = torch.softmax(self.bary_logits, -1)
        return torch.where(self.learnable[:, None], soft, self.bary_fixed)

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
        norm = raw.norm(dim=-1, keepdim=True)
        return raw * (bound * torch.tanh(norm) / norm.clamp_min(1e-9))

    # ------------------------------------------------------------------ forward
    def forward(self, v_shaped: torch.Tensor, vertices: torch.Tensor, transforms: torch.Tensor,
                transl: torch.Tensor | None, sh_degree: int) -> PosedGaussians:
        """Pose the Gaussians for B frames.

        v_shaped: (B, V, 3) canonical vertices; vertices: (B, V, 3) posed vertices;
        transforms: (B, J, 4, 4) LBS joint transforms (index 0 = root); transl: (B, 3) or None;
        sh_degree: SH degree in use (coefficients above it are dropped).
        """
        b = v_shaped.shape[0]
        rot = transforms[..., :3, :3]
        m_v = torch.einsum("vj,bjxy->bvxy", self.lbs_weights, rot)  # (B, V, 3, 3)
        disp = self.displacement()
        if disp is not None:
            off = disp[None] * vertex_normals(v_shaped, self.faces)
            v_c = v_shaped + off
            v_p = vertices + torch.einsum("bvxy,bvy->bvx", m_v, off)
        else:
            v_c, v_p = v_shaped, vertices
        bary = self.barycentric()
        x_c = (v_c[:, self.anchors] * bary[None, ..., None]).sum(2)
        x_p = (v_p[:, self.anchors] * bary[None, ..., None]).sum(2)
        l_off = self.offsets()
        on_face = self.learnable & (self.face >= 0)
        if bool(on_face.any()):
            idx = torch.nonzero(on_face)[:, 0]
            fidx = self.face[idx]
            n_c = face_normals(v_c, self.faces[fidx])
            n_p = face_normals(v_p, self.faces[fidx])
            x_c = x_c.index_add(1, idx, n_c * l_off[idx, None])
            x_p = x_p.index_add(1, idx, n_p * l_off[idx, None])
        # rotation of each vertex's blended LBS frame, blended over each point's anchors
        eye = torch.eye(3, dtype=m_v.dtype, device=m_v.device)
        q_v = xyzw_to_wxyz(roma.rotmat_to_unitquat(roma.special_gramschmidt(m_v + 1e-6 * eye)))
        q_a = q_v[:, self.anchors]  # (B, P, 3, 4)
        sign = torch.where((q_a * q_a[:, :, :1]).sum(-1, keepdim=True) < 0, -1.0, 1.0)
        q_p = (q_a * (sign * bary[None, ..., None])).sum(2)
        q_p = q_p / q_p.norm(dim=-1, keepdim=True).clamp_min(1e-9)

        scale_raw = self.scale_raw.expand(b, -1, -1)
        quat = self.quat.expand(b, -1, -1)
        opacity_raw = self.opacity_raw[:, 0].expand(b, -1)
        k = num_sh_bases(sh_degree)
        sh = torch.cat([self.sh_dc, self.sh_rest[:, : k - 1]], 1).expand(b, -1, -1, -1)
        if self.omega is not None:
            # translation canonical -> posed, expressed in the root joint's frame
            root = transforms[:, 0]
            tr = transl if transl is not None else torch.zeros(b, 3, dtype=x_p.dtype,
                                                               device=x_p.device)
            x_root = torch.einsum("byx,bpy->bpx", root[:, :3, :3],
                                  x_p - tr[:, None] - root[:, None, :3, 3])
            feat = torch.cat([(x_c - self.center) / self.extent, (x_root - x_c) / self.extent], -1)
            order = self.point_order
            heads = self.omega(feat[:, order].transpose(1, 2))  # (B, P, k) in sequence order
            d_s, d_q, d_o, d_c = (torch.empty_like(h).index_copy(1, order, h) for h in heads)
            scale_raw = scale_raw + d_s
            quat = quat + d_q
            opacity_raw = opacity_raw + d_o[..., 0]
            sh = torch.cat([sh[:, :, :1] + d_c[:, :, None], sh[:, :, 1:]], 2)
        if self.irradiance is not None:
            with torch.no_grad():
                n_v = vertex_normals(v_p.detach(), self.faces)[:, self.anchors]  # (B, P, 3, 3)
                n_p = (n_v * bary.detach()[None, ..., None]).sum(2)
                n_p = n_p / n_p.norm(dim=-1, keepdim=True).clamp_min(1e-9)
            # elementwise product + sum rather than a matmul: BLAS's reduction over B*P points for
            # the coefficients' gradient is not reproducible run to run, this is
            gain = (irradiance_basis(n_p)[..., None] * self.irradiance).sum(-2)
            sh = shade_sh(sh, gain)
        smin = self.cfg.scale_min
        smax = self.scale_max_per_point()[None, :, None]
        scales = smin + (smax - smin) * torch.sigmoid(scale_raw)
        q_c = quat / quat.norm(dim=-1, keepdim=True).clamp_min(1e-9)
        quats = quat_mul(q_p, q_c)
        return PosedGaussians(
            means=x_p, quats=quats, scales=scales, opacities=torch.sigmoid(opacity_raw),
            colors=sh, canonical=x_c, displacement=disp, normal_offset=l_off,
            sh_degree=sh_degree,
        )

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
