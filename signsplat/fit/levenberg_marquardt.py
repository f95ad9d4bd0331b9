"""Levenberg-Marquardt over a whole sequence: per-frame parameters, cameras and betas (float64).

Why: the fit's objective is badly conditioned. The torso chain between the observed hips,
shoulders and face (pelvis tilt, spine1..3, neck, collars) is pinned by the data only at its
ends; how the bending is shared along the chain is decided by the priors alone, whose curvature
is ~1e4 times smaller than the data's. First-order steps (Adam, and L-BFGS within a
few hundred iterations) crawl along those directions, which left a 2-3 degree pelvis tilt (legs
40 mm off) with perfect keypoints. A Gauss-Newton step solves both scales at once (and reaches the
cameras to ~0.02 degrees with perfect keypoints).

Structure: each frame has P ~ 130 unknowns; the accelerations of the smoothness term couple a
frame to its +-2 neighbours, so the per-frame part of the Gauss-Newton matrix is block-banded
(bandwidth 3P, solved by a banded Cholesky: O(T P^3)). The global unknowns (the free cameras'
rotation/translation increments and the betas, Y <= 6 V + 10) border it and are eliminated by
a Schur complement. The robust kernel is handled by iteratively reweighted least squares
(weights from the current residuals); a step is accepted only when the exact objective
decreases, with Marquardt damping (lambda diag(H)). Jacobians are forward differences in
float64.

Objective: the same terms and weights as :mod:`signsplat.fit.objective` summed over frames
(i.e. ``T`` times the stages' loss): robust reprojection, near plane, body-pose/jaw/expression/
hand priors, upright, the single-view anchor, the accelerations of the 3D keypoints and pose
vectors, the shape prior and the camera anchor.
"""

from __future__ import annotations

import copy
import logging

import numpy as np
import torch

from signsplat.fit import objective as obj
from signsplat.fit.cameras import project

log = logging.getLogger(__name__)

#: Parameter blocks per group, in the order of the per-frame vector.
GROUP_BLOCKS = {"root": ("global_orient", "transl"), "body": ("body_pose",),
                "face": ("jaw_pose", "expression"), "hands": ("left_free", "right_free")}
PER_FRAME_GROUPS = tuple(GROUP_BLOCKS)
_ALL_BLOCKS = ("global_orient", "transl", "body_pose", "jaw_pose", "expression", "left_free",
               "right_free")


def _kpm64(problem):
    """A float64 copy of the keypoint model, made once per problem."""
    m = getattr(problem, "_kpm64", None)
    if m is None:
        m = copy.deepcopy(problem.kpm).double()
        problem._kpm64 = m
    return m


class SequenceResiduals:
    """The LM stage's objective written as residuals of the whole sequence: per-frame residual
    vectors (:meth:`outputs`, for given global unknowns), the global unknowns themselves (the
    free cameras' increments and the betas: :meth:`pack_global` / :meth:`set_global`), and
    the exact objective (:meth:`total`)."""

    def __init__(self, problem, params, cams, stage, blocks, global_groups=()):
        dt = torch.float64
        self.kpm = _kpm64(problem)
        self.params = params
        self.limits = params.limits
        self.blocks = blocks
        with torch.no_grad():
            K, R, t = cams()
            self.K, self.R, self.t = K.to(dt), R.to(dt), t.to(dt)
            self.up = (obj.level_rig_up(self.R) if problem.level_cameras else
                       (None if problem.up is None else problem.up.to(dt)))
            self.values = {n: getattr(params, n).detach().to(dt).clone() for n in _ALL_BLOCKS}
            self.betas = params.betas.detach().to(dt).clone()
            self.K0, self.R0, self.t0 = (cams.K0.to(dt), cams.R0.to(dt), cams.t0.to(dt))
            self.focal = torch.exp(cams.log_focal.detach().to(dt))[:, :, None]
            self.free = cams.free.detach().to(dt)
            self.rotvec = cams.rotvec.detach().to(dt).clone()
            self.dt = cams.dt.detach().to(dt).clone()
        self.level = bool(problem.level_cameras)
        self.problem_up = None if problem.up is None else problem.up.to(dt)
        #: global unknowns: rotvec and dt of the free cameras, then betas
        self.free_views = [int(v) for v in torch.nonzero(self.free[:, 0] > 0)[:, 0]] \
            if "cameras" in global_groups else []
        self.use_betas = "betas" in global_groups
        self.sizes = [self.values[n].shape[1] for n in blocks]
        self.w = problem.weights
        self.obs = problem.obs.to(dt)  # (V,T,133,3)
        self.kpw = obj.part_weight_vector(stage.parts, dtype=dt, device=self.obs.device)
        self.sigma = problem.sigma_px if stage.sigma_px is None else stage.sigma_px
        self.anchor = ({k: v.to(dt) for k, v in problem.anchor.items()}
                       if self.w.anchor > 0 else {})
        self.kernel = problem.kernel
        self.pose_w = obj.body_pose_weights(self.w, dtype=dt, device=self.obs.device)
        self.pose_mean = (torch.zeros(63, dtype=dt) if problem.pose_mean is None
                          else problem.pose_mean.to(dt))
        self.smooth = stage.smooth and (self.w.smooth_keypoints > 0 or self.w.smooth_pose > 0)
        T = self.values["transl"].shape[0]
        contig = (torch.ones(max(T - 2, 0), dtype=torch.bool) if problem.contiguous is None
                  else problem.contiguous.bool())
        self.contig = contig
        self.T = T

    # -- packing ---------------------------------------------------------------------------
    def pack_global(self) -> torch.Tensor:
        parts = [self.rotvec[self.free_views].reshape(-1), self.dt[self.free_views].reshape(-1)]
        if self.use_betas:
            parts.append(self.betas.reshape(-1))
        return torch.cat(parts)

    def set_global(self, y: torch.Tensor) -> None:
        """Cameras (R = exp(rotvec) R0, t = t0 + dt, as CameraParams) and betas from ``y``."""
        import roma

        n = len(self.free_views)
        if n:
            self.rotvec = self.rotvec.clone()
            self.dt = self.dt.clone()
            self.rotvec[self.free_views] = y[:3 * n].reshape(n, 3)
            self.dt[self.free_views] = y[3 * n:6 * n].reshape(n, 3)
        if self.use_betas:
            self.betas = y[6 * n:].reshape(1, -1).clone()
        self.R = roma.rotvec_to_rotmat(self.rotvec * self.free) @ self.R0
        self.t = self.t0 + self.dt * self.free
        K = self.K0.clone()
        K[:, :2, :2] = self.K0[:, :2, :2] * self.focal
        self.K = K
        if self.level:
            self.up = obj.level_rig_up(self.R)

    def pack(self) -> torch.Tensor:
        return torch.cat([self.values[n] for n in self.blocks], dim=1)

    def unpack(self, x: torch.Tensor, frames: torch.Tensor) -> dict[str, torch.Tensor]:
        """x (B,P) of the frames ``frames (B,)`` -> every block (B,k)."""
        out = {n: self.values[n][frames] for n in _ALL_BLOCKS}
        parts = torch.split(x, self.sizes, dim=1)
        for n, p in zip(self.blocks, parts):
            out[n] = p
        return out

    def store(self, x: torch.Tensor) -> None:
        for n, p in zip(self.blocks, torch.split(x, self.sizes, dim=1)):
            self.values[n] = p.clone()

    # -- forward ---------------------------------------------------------------------------
    def _pose_vec(self, b: dict[str, torch.Tensor]) -> torch.Tensor:
        return torch.cat([b["global_orient"], b["body_pose"], b["jaw_pose"],
                          b["left_free"] * 0.1, b["right_free"] * 0.1], dim=-1)

    def keypoints(self, b: dict[str, torch.Tensor]) -> torch.Tensor:
        from signsplat.body import hand_limits as hl

        B = b["transl"].shape[0]
        _, kp, _ = self.kpm(
            betas=self.betas.expand(B, -1), expression=b["expression"],
            global_orient=b["global_orient"], body_pose=b["body_pose"], jaw_pose=b["jaw_pose"],
            left_hand_pose=hl.free_to_hand_pose(b["left_free"], self.limits["left"]),
            right_hand_pose=hl.free_to_hand_pose(b["right_free"], self.limits["right"]),
            transl=b["transl"])
        return kp

    def outputs(self, x: torch.Tensor, frames: torch.Tensor, irls: torch.Tensor | None,
                kp: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor, int]:
        """Per-frame outputs of ``x (B,P)`` (frames ``frames (B,)``).

        Returns (features (B,M): IRLS-weighted data residuals, near-plane and prior residuals,
        then the smoothness features sqrt(w_k) * keypoints and sqrt(w_p) * pose vector;
        per-frame robust cost without smoothness (B,); number of leading residual entries).
        ``irls (V,B,133)``: least-squares weights of the data residuals (None: from these).
        ``kp (B,133,3)``: the keypoints of ``x`` when already known (camera perturbations).
        """
        from signsplat.body import hand_limits as hl
        from signsplat.fit.robust import kernel as robust_kernel

        w = self.w
        B = len(frames)
        b = self.unpack(x, frames)
        if kp is None:
            kp = self.keypoints(b)
        uv, z = project(kp, self.K, self.R, self.t)  # (V,B,133,2), (V,B,133)
        obs = self.obs[:, frames]
        d = uv - obs[..., :2]
        r2 = (d ** 2).sum(-1)
        conf = obs[..., 2] * self.kpw
        front = (z > 0.05).to(d.dtype)
        if irls is None:
            irls = _irls_weights(self.kernel, r2, self.sigma)
        wd = w.reprojection * conf * front
        data = (torch.sqrt(wd * irls)[..., None] * d).permute(1, 0, 2, 3).reshape(B, -1)
        robust = (wd * robust_kernel(self.kernel)(r2, self.sigma)).sum((0, 2))
        beh = ((conf > 0).to(d.dtype) * torch.relu(0.05 - z) ** 2).sum((0, 2))
        quad = [torch.sqrt(w.behind_camera * beh + 1e-30)[:, None],
                torch.sqrt(self.pose_w) * (b["body_pose"] - self.pose_mean),
                np.sqrt(w.jaw) * b["jaw_pose"], np.sqrt(w.expression) * b["expression"]]
        if w.hand_pose > 0:
            for side in ("left", "right"):
                anat = hl.free_to_anatomical(b[f"{side}_free"], self.limits[side])
                quad.append(np.sqrt(w.hand_pose) * anat.reshape(B, -1))
        if w.upright > 0:
            import roma

            pelvis_up = roma.rotvec_to_rotmat(b["global_orient"])[..., :, 1]
            up = self.up if self.up is not None else torch.tensor([0.0, 1.0, 0.0], dtype=d.dtype)
            quad.append(np.sqrt(w.upright) * (pelvis_up - up))
        for name in ("global_orient", "body_pose", "transl"):  # single-view refinement
            if name in self.anchor:
                quad.append(np.sqrt(w.anchor) * (b[name] - self.anchor[name][frames]))
        quad = torch.cat(quad, dim=1)
        cost = robust + (quad ** 2).sum(1)
        feats = [data, quad]
        if self.smooth:
            feats += [np.sqrt(w.smooth_keypoints) * kp.reshape(B, -1),
                      np.sqrt(w.smooth_pose) * self._pose_vec(b)]
        return torch.cat(feats, dim=1), cost, data.shape[1] + quad.shape[1]

    def smooth_cost(self, feats: torch.Tensor, head: int) -> torch.Tensor:
        """Sum over contiguous triplets of |acceleration|^2 of the smoothness features (T,.)."""
        if not self.smooth or self.T < 3:
            return feats.new_zeros(())
        f = feats[:, head:]
        acc = f[2:] - 2 * f[1:-1] + f[:-2]
        return ((acc ** 2).sum(1) * self.contig.to(f.dtype)).sum()

    def shape_residual(self) -> torch.Tensor:
        """sqrt(T w_shape) betas: the shape prior on the sum-over-frames scale."""
        return np.sqrt(self.T * self.w.shape) * self.betas.reshape(-1)

    def camera_residual(self) -> torch.Tensor:
        """sqrt(T w_camera_anchor) (rotvec, dt) of the free cameras (their change from init)."""
        v = self.free_views
        return np.sqrt(self.T * self.w.camera_anchor) * torch.cat(
            [self.rotvec[v].reshape(-1), self.dt[v].reshape(-1)])

    def total(self, x: torch.Tensor) -> torch.Tensor:
        """Exact objective of the whole sequence (sum over frames, + T x the global priors)."""
        frames = torch.arange(self.T)
        feats, cost, head = self.outputs(x, frames, None)
        shape = (self.shape_residual() ** 2).sum() if self.use_betas else 0.0
        return cost.sum() + self.smooth_cost(feats, head) + shape + \
            (self.camera_residual() ** 2).sum()


def _irls_weights(kernel: str, r2: torch.Tensor, sigma: float) -> torch.Tensor:
    """d rho / d r2 of the robust kernels of :mod:`signsplat.fit.robust`."""
    s2 = float(sigma) ** 2
    if kernel == "geman_mcclure":
        return (s2 / (s2 + r2)) ** 2
    if kernel == "huber":
        return torch.where(r2 > s2, float(sigma) / torch.sqrt(r2.clamp_min(1e-12)),
                           torch.ones_like(r2))
    return torch.ones_like(r2)


def _jacobian(resid: SequenceResiduals, x: torch.Tensor, frames: torch.Tensor, irls: torch.Tensor,
              f0: torch.Tensor, step: float = 1e-6, chunk: int = 32) -> torch.Tensor:
    """Forward-difference Jacobian (B,M,P) of the per-frame features."""
    B, P = x.shape
    J = torch.empty(B, f0.shape[1], P, dtype=x.dtype)
    for s in range(0, P, chunk):
        cols = torch.arange(s, min(s + chunk, P))
        n = len(cols)
        xp = x.unsqueeze(0).repeat(n, 1, 1)
        xp[torch.arange(n), :, cols] += step
        f, _, _ = resid.outputs(xp.reshape(n * B, P), frames.repeat(n), irls.repeat(1, n, 1))
        J[:, :, s:s + n] = ((f.reshape(n, B, -1) - f0) / step).permute(1, 2, 0)
    return J


def _global_jacobian(resid: SequenceResiduals, x: torch.Tensor, frames: torch.Tensor,
                     irls: torch.Tensor, f0: torch.Tensor, step: float = 1e-6) -> torch.Tensor:
    """Forward-difference Jacobian (B,M,Y) of the per-frame features in the global unknowns.

    The camera columns reuse the body's keypoints (only the projection changes)."""
    y0 = resid.pack_global()
    J = torch.empty(len(frames), f0.shape[1], len(y0), dtype=x.dtype)
    n_cam = 6 * len(resid.free_views)
    kp0 = resid.keypoints(resid.unpack(x, frames)) if n_cam else None
    for k in range(len(y0)):
        y = y0.clone()
        y[k] += step
        resid.set_global(y)
        f, _, _ = resid.outputs(x, frames, irls, kp0 if k < n_cam else None)
        J[:, :, k] = (f - f0) / step
    resid.set_global(y0)
    return J


def _normal_equations(resid: SequenceResiduals, x: torch.Tensor, chunk: int):
    """Gauss-Newton normal equations of the whole sequence.

    Returns (per-frame block in lower banded storage ``(3P, T*P)`` - frames couple to +-2
    neighbours through the accelerations -, its gradient (T*P,), the coupling ``C (T*P, Y)``
    to the global unknowns, their block ``D (Y,Y)`` and gradient ``(Y,)``), numpy float64.
    """
    T, P = x.shape
    Y = len(resid.pack_global())
    frames = torch.arange(T)
    kp = resid.keypoints(resid.unpack(x, frames))
    uv, _ = project(kp, resid.K, resid.R, resid.t)
    irls_all = _irls_weights(resid.kernel, ((uv - resid.obs[..., :2]) ** 2).sum(-1), resid.sigma)
    Hd = torch.zeros(T, P, P, dtype=x.dtype)
    g = torch.zeros(T, P, dtype=x.dtype)
    C = torch.zeros(T, P, Y, dtype=x.dtype)
    D = torch.zeros(Y, Y, dtype=x.dtype)
    gy = torch.zeros(Y, dtype=x.dtype)
    feats, G, Gy = [], [], []
    head = 0
    for s in range(0, T, chunk):
        fr = frames[s:s + chunk]
        f0, _, head = resid.outputs(x[fr], fr, irls_all[:, fr])
        J = _jacobian(resid, x[fr], fr, irls_all[:, fr], f0)
        Jh, rh = J[:, :head], f0[:, :head]
        Hd[fr] = Jh.transpose(1, 2) @ Jh
        g[fr] = (Jh.transpose(1, 2) @ rh[..., None])[..., 0]
        feats.append(f0[:, head:])
        G.append(J[:, head:])
        if Y:
            Jy = _global_jacobian(resid, x[fr], fr, irls_all[:, fr], f0)
            C[fr] = Jh.transpose(1, 2) @ Jy[:, :head]
            D += (Jy[:, :head].transpose(1, 2) @ Jy[:, :head]).sum(0)
            gy += (Jy[:, :head].transpose(1, 2) @ rh[..., None])[..., 0].sum(0)
            Gy.append(Jy[:, head:])
    if resid.free_views and resid.w.camera_anchor > 0:  # cameras' pull towards their init
        nc = 6 * len(resid.free_views)
        D[:nc, :nc] += resid.T * resid.w.camera_anchor * torch.eye(nc, dtype=x.dtype)
        gy[:nc] += np.sqrt(resid.T * resid.w.camera_anchor) * resid.camera_residual()
    if resid.use_betas:  # shape prior
        nb = resid.betas.numel()
        D[Y - nb:, Y - nb:] += resid.T * resid.w.shape * torch.eye(nb, dtype=x.dtype)
        gy[Y - nb:] += resid.T * resid.w.shape * resid.betas.reshape(-1)
    H1 = torch.zeros(max(T - 1, 0), P, P, dtype=x.dtype)  # block (t+1, t)
    H2 = torch.zeros(max(T - 2, 0), P, P, dtype=x.dtype)  # block (t+2, t)
    if resid.smooth and T >= 3:
        f = torch.cat(feats)
        G = torch.cat(G)  # (T,F,P)
        m = resid.contig.to(x.dtype)  # (T-2,) triplet centred at c = index + 1
        acc = (f[2:] - 2 * f[1:-1] + f[:-2]) * m[:, None]
        coef = (1.0, -2.0, 1.0)
        GtG = G.transpose(1, 2) @ G  # (T,P,P)
        G10 = G[1:].transpose(1, 2) @ G[:-1]  # (T-1,P,P): G_{t+1}^T G_t
        G20 = G[2:].transpose(1, 2) @ G[:-2]
        for k in range(3):
            g[k:T - 2 + k] += coef[k] * (G[k:T - 2 + k].transpose(1, 2) @ acc[..., None])[..., 0]
            Hd[k:T - 2 + k] += (coef[k] ** 2) * m[:, None, None] * GtG[k:T - 2 + k]
        # (c, c-1) from k=1,l=0 and (c+1, c) from k=2,l=1; (c+1, c-1) from k=2,l=0
        H1[0:T - 2] += coef[1] * coef[0] * m[:, None, None] * G10[0:T - 2]
        H1[1:T - 1] += coef[2] * coef[1] * m[:, None, None] * G10[1:T - 1]
        H2 += coef[2] * coef[0] * m[:, None, None] * G20
        if Y:
            Gy = torch.cat(Gy)  # (T,F,Y)
            Ay = (Gy[2:] - 2 * Gy[1:-1] + Gy[:-2]) * m[:, None, None]  # (T-2,F,Y)
            D += (Ay.transpose(1, 2) @ Ay).sum(0)
            gy += (Ay.transpose(1, 2) @ acc[..., None])[..., 0].sum(0)
            for k in range(3):
                C[k:T - 2 + k] += coef[k] * (G[k:T - 2 + k].transpose(1, 2) @ Ay)
    n = T * P
    band = np.zeros((3 * P, n))
    a = np.arange(P)
    ii, jj = np.meshgrid(a, a, indexing="ij")  # row a of block (t+off), column b of t
    for blocks, off in ((Hd, 0), (H1, 1), (H2, 2)):
        d = off * P + ii - jj
        ok = (d >= 0) & (d < 3 * P)
        B = blocks.numpy()
        for t in range(B.shape[0]):
            band[d[ok], t * P + jj[ok]] = B[t][ok]
    return (band, g.reshape(-1).numpy(), C.reshape(n, Y).numpy(), D.numpy(), gy.numpy())


def _solve(band, g, C, D, gy, lam):
    """Damped step of the bordered banded system (Schur complement on the global block)."""
    from scipy.linalg import solveh_banded

    A = band.copy()
    A[0] += lam * np.maximum(band[0], 1e-9)
    if C.shape[1] == 0:
        return -solveh_banded(A, g, lower=True, check_finite=False), np.zeros(0)
    Z = solveh_banded(A, np.concatenate([g[:, None], C], axis=1), lower=True,
                      check_finite=False)
    Dl = D + lam * np.diag(np.maximum(np.diag(D), 1e-9))
    S = Dl - C.T @ Z[:, 1:]
    dy = -np.linalg.solve(S, gy - C.T @ Z[:, 0])
    dx = -Z[:, 0] - Z[:, 1:] @ dy
    return dx, dy


def run_lm(problem, params, cams, stage, sel: slice = slice(None), chunk: int = 64
           ) -> list[float]:
    """Levenberg-Marquardt on the groups of ``stage`` over the whole sequence.

    Per-frame groups form a banded system; ``cameras`` and ``betas`` (global unknowns) are
    eliminated by a Schur complement.

    ``stage.iterations`` bounds the iterations, ``stage.tolerance`` ends them earlier; ``sel``
    must be the whole sequence. Returns the objective after each iteration (same scale as the
    other stages' losses: mean over frames, without the shape prior).
    """
    from scipy.linalg import LinAlgError

    if not set(stage.groups) & set(PER_FRAME_GROUPS):
        raise ValueError(f"stage {stage.name!r}: optimizer lm needs at least one per-frame "
                         f"group of {list(PER_FRAME_GROUPS)}")
    if sel != slice(None):
        raise ValueError(f"stage {stage.name!r}: optimizer lm runs on the whole sequence "
                         "(warm_start must be false)")
    blocks = [n for g in PER_FRAME_GROUPS if g in stage.groups for n in GROUP_BLOCKS[g]]
    resid = SequenceResiduals(problem, params, cams, stage, blocks,
                    [g for g in ("cameras", "betas") if g in stage.groups])
    T = resid.T
    x = resid.pack()
    y = resid.pack_global()
    resid.set_global(y)
    P = x.shape[1]
    lam = 1e-3
    with torch.no_grad():
        cost = float(resid.total(x))
        history = [cost / max(T, 1)]
        for it in range(stage.iterations):
            system = _normal_equations(resid, x, chunk)
            improved = False
            for _ in range(8):
                try:
                    dx, dy = _solve(*system, lam)
                except (LinAlgError, ValueError):
                    lam = min(lam * 10, 1e9)
                    continue
                if not (np.isfinite(dx).all() and np.isfinite(dy).all()):
                    lam = min(lam * 10, 1e9)
                    continue
                cand = x + torch.as_tensor(dx, dtype=x.dtype).reshape(T, P)
                y1 = y + torch.as_tensor(dy, dtype=y.dtype)
                resid.set_global(y1)
                c1 = float(resid.total(cand))
                if np.isfinite(c1) and c1 < cost:
                    x, y, cost, improved = cand, y1, c1, True
                    lam = max(lam / 3, 1e-9)
                    break
                resid.set_global(y)
                lam = min(lam * 4, 1e9)
            history.append(cost / max(T, 1))
            log.debug("lm %s iteration %d: objective %.6g, damping %.2g", stage.name, it,
                      history[-1], lam)
            if not improved or history[-2] - history[-1] < stage.tolerance * max(history[-2],
                                                                                  1e-9):
                break
        resid.store(x)
        for n in blocks:
            getattr(params, n).copy_(resid.values[n].to(getattr(params, n).dtype))
        if resid.use_betas:
            params.betas.copy_(resid.betas.to(params.betas.dtype))
        if resid.free_views:
            cams.rotvec.copy_(resid.rotvec.to(cams.rotvec.dtype))
            cams.dt.copy_(resid.dt.to(cams.dt.dtype))
    return history[1:]
