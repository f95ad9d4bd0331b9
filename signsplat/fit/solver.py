"""The optimisation loop shared by the multi-view and single-view fits (torch, CPU or GPU).

A fit is a list of :class:`Stage` s. Each stage optimises some parameter groups (``betas``,
``root``, ``body``, ``hands``, ``face``, ``cameras``) with Adam and a cosine learning-rate
decay, batched over the frames it is given. :func:`run_warm_started` runs a stage chunk by chunk
along the sequence, initialising each chunk from the last solved frame of the previous one.
A stage with silhouette weights also poses the full mesh and adds the mask terms of
:mod:`signsplat.fit.silhouette`; a stage with a flow weight adds the optical-flow term of
:mod:`signsplat.fit.flow`. Other stages never touch the masks, the images or the flow.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field

import numpy as np
import torch

from signsplat.fit import objective as obj
from signsplat.fit.bodyfit import FitParams, KeypointModel
from signsplat.fit.cameras import CameraParams, project
from signsplat.fit.flow import FlowTargets, flow_term
from signsplat.fit.silhouette import (
    MatchCache,
    SilhouetteTargets,
    silhouette_terms,
    targets_from_masks,
)

log = logging.getLogger(__name__)

GROUPS = ("betas", "root", "body", "hands", "face", "cameras")
#: the mask terms a stage can weight (signsplat.fit.silhouette.silhouette_terms)
SILHOUETTE_TERMS = ("inside", "cover")


#: the part of the fit schema that holds a stage (its defaults live there)
STAGE_SCHEMA = "stages/fit.schema.yaml#/$defs/stage"


@dataclass
class Stage:
    """One optimisation stage (config ``fit.<mode>.stages[i]``; defaults in the schema).

    Build it with :meth:`from_config` from a validated stage dict (:func:`stage_config` fills
    the defaults of a stage written in code). The fields with a value here stand for a
    setting the schema leaves absent, which means "off".
    """

    name: str
    iterations: int
    lr: float
    groups: tuple[str, ...]
    smooth: bool
    #: run chunk by chunk, each chunk starting from the previous one's last frame
    warm_start: bool
    final_lr_fraction: float
    #: adam (cosine-decayed lr), lbfgs (strong Wolfe line search) or lm (per-frame
    #: Levenberg-Marquardt, cameras and betas fixed: signsplat.fit.levenberg_marquardt; lr
    #: unused)
    optimizer: str
    #: lm: stop after an iteration that lowers the objective by less than this fraction
    tolerance: float
    parts: dict[str, float] = field(default_factory=dict)  # keypoint part weights
    lr_scale: dict[str, float] = field(default_factory=dict)  # per group, relative to lr
    sigma_px: float | None = None  # robust-kernel scale of this stage (None: the problem's)
    #: weights of the mask terms (signsplat.fit.silhouette): {"inside": w, "cover": w} in
    #: px^-2; none given = the masks are not used and nothing is computed
    silhouette: dict[str, float] = field(default_factory=dict)
    #: Adam steps between two contour matchings of the cover term (1 = every step)
    rematch_every: int = 1
    #: Adam steps between two choices of the flow term's vertices (None: rematch_every)
    flow_rematch_every: int | None = None
    #: weight of the optical-flow term (signsplat.fit.flow) in px^-2; 0 = the images are not
    #: read and no flow is computed
    flow: float = 0.0
    #: views whose held-out keypoint error at the camera initialisation (Problem.view_px) is
    #: at most this keep their cameras in this stage; None = every free camera moves
    hold_cameras_within_px: float | None = None

    def __post_init__(self):
        bad = set(self.silhouette) - set(SILHOUETTE_TERMS)
        if bad:
            raise ValueError(f"stage {self.name!r}: unknown silhouette term(s) {sorted(bad)}; "
                             f"known {list(SILHOUETTE_TERMS)}")
        if self.optimizer == "lm" and (self.uses_silhouette or self.uses_flow):
            raise ValueError(f"stage {self.name!r}: the silhouette and flow terms need a "
                             "gradient optimizer (adam or lbfgs), not lm")
        if self.optimizer == "lm" and self.hold_cameras_within_px is not None:
            raise ValueError(f"stage {self.name!r}: hold_cameras_within_px needs a gradient "
                             "optimizer (adam or lbfgs), not lm")

    @property
    def uses_silhouette(self) -> bool:
        return any(float(v) > 0 for v in self.silhouette.values())

    @property
    def uses_flow(self) -> bool:
        return self.flow > 0

    @property
    def holds_cameras(self) -> bool:
        """This stage moves cameras and holds those whose keypoints agree."""
        return self.hold_cameras_within_px is not None and "cameras" in self.groups

    @classmethod
    def from_config(cls, cfg: dict) -> Stage:
        """From a validated stage dict (the schema has filled its defaults)."""
        groups = tuple(cfg["groups"])
        bad = set(groups) - set(GROUPS)
        if bad:
            raise ValueError(f"stage {cfg.get('name')!r}: unknown group(s) {sorted(bad)}; "
                             f"known {list(GROUPS)}")
        optional = {k: cfg[k] for k in ("sigma_px", "rematch_every", "flow_rematch_every",
                                        "flow", "hold_cameras_within_px") if k in cfg}
        return cls(name=cfg["name"], iterations=int(cfg["iterations"]), lr=float(cfg["lr"]),
                   groups=groups, smooth=bool(cfg["smooth"]),
                   warm_start=bool(cfg["warm_start"]),
                   final_lr_fraction=float(cfg["final_lr_fraction"]),
                   optimizer=cfg["optimizer"], tolerance=float(cfg["tolerance"]),
                   parts=dict(cfg.get("parts", {})),
                   lr_scale=dict(cfg.get("lr_scale", {})),
                   silhouette=dict(cfg.get("silhouette", {})), **optional)


def stage_config(**settings) -> dict:
    """A stage dict written in code (e.g. the single-view hypotheses' stage), validated with
    the schema's defaults filled in: ``Stage.from_config(stage_config(name=..., ...))``."""
    from signsplat.config import validate

    return validate(dict(settings), STAGE_SCHEMA, f"stage {settings.get('name')!r}")


def stages_using(stages: list[dict], *terms: str) -> list[str]:
    """Names of the stage configs whose :class:`Stage` has any of the properties ``terms``
    (``uses_silhouette``, ``uses_flow``)."""
    return [s["name"] for s in stages
            if any(getattr(Stage.from_config(s), term) for term in terms)]


@dataclass
class Problem:
    """Everything a stage needs besides the parameters.

    obs (V,T,133,3) torch; robust kernel name and scale in pixels (config ``fit.robust``);
    contiguous (T-2,) bool. Build it with :func:`make_problem` from the validated config.
    """

    kpm: KeypointModel
    obs: torch.Tensor
    weights: obj.Weights
    kernel: str
    sigma_px: float
    contiguous: torch.Tensor | None = None
    anchor: dict[str, torch.Tensor] = field(default_factory=dict)
    pose_mean: torch.Tensor | None = None  # (63,) body-pose prior mean
    up: torch.Tensor | None = None  # (3,) world vertical in the fit frame (upright prior)
    #: the vertical follows the cameras being solved (level rig: see objective.level_rig_up)
    level_cameras: bool = False
    #: mask targets for stages with silhouette weights (None: no masks were given)
    silhouette: SilhouetteTargets | None = None
    #: flow fields for stages with a flow weight (None: no images were given)
    flow: FlowTargets | None = None
    #: config ``fit.multiview.flow`` (clamp_px, max_vertices) when ``flow`` is given
    flow_settings: dict = field(default_factory=dict)
    #: (63,) bool body-pose values held at ``pose_mean`` (legs no view sees: config
    #: ``fit.hold_unseen_legs``); None holds nothing
    held_pose: torch.Tensor | None = None
    #: (V,) each view's held-out keypoint error (px) at the camera initialisation (NaN: not
    #: measured, or a camera that stays fixed anyway); what a stage's
    #: ``hold_cameras_within_px`` compares. None: not measured
    view_px: np.ndarray | None = None

    def held_views(self, stage: Stage) -> list[int]:
        """Views whose cameras ``stage`` holds: those it optimises whose keypoints agreed
        across the views to within its ``hold_cameras_within_px`` (none when unmeasured)."""
        if not stage.holds_cameras or self.view_px is None:
            return []
        return [v for v, px in enumerate(self.view_px) if px <= stage.hold_cameras_within_px]

    @property
    def legs_held(self) -> list[str]:
        """Sides whose legs :attr:`held_pose` holds (for the fit log)."""
        if self.held_pose is None:
            return []
        return [side for side, (joints, _) in obj.LEG_SIDES.items()
                if bool(self.held_pose[3 * (joints[0] - 1)])]


def make_problem(kpm: KeypointModel, obs: np.ndarray, cfg: dict, frames: np.ndarray | None = None,
                 anchor: dict[str, np.ndarray] | None = None, weights: dict | None = None,
                 dtype=torch.float32, device="cpu", up: np.ndarray | None = None,
                 level_cameras: bool = False, masks: np.ndarray | None = None,
                 flow: FlowTargets | None = None, image_sizes=None,
                 view_px: np.ndarray | None = None) -> Problem:
    """A :class:`Problem` from the ``fit`` config section.

    obs (V,T,133,3); keypoints the body model cannot place (``regressor.valid`` False) get
    confidence 0. ``weights`` overrides entries of ``cfg['weights']``. ``up``: the world
    vertical of the upright prior; with ``level_cameras`` (and ``up`` given, i.e. the rig's
    x axes span a plane) the vertical is recomputed from the current cameras in every step.
    ``masks (V,T,H,W)`` bool person masks: the targets of stages with silhouette weights.
    ``flow``: the flow fields of stages with a flow weight (:func:`signsplat.fit.flow.flow_targets`;
    the term's settings come from ``cfg['multiview']['flow']``). ``image_sizes (V,2)``
    (width, height) px: a leg keypoint outside its image does not count as seen when the
    legs no view sees are held (``fit.hold_unseen_legs``, :func:`objective.unseen_legs`).
    ``view_px (V,)``: each view's held-out keypoint error at the camera initialisation, what
    a stage's ``hold_cameras_within_px`` compares (None: no camera is held).
    """
    obs_t = torch.as_tensor(np.asarray(obs), dtype=dtype, device=device).clone()
    valid = getattr(kpm.regressor, "valid", None)
    if valid is not None:
        obs_t[..., 2] = obs_t[..., 2] * valid.to(device=device, dtype=dtype)
    legs = obj.unseen_legs(obs_t, image_sizes) if cfg["hold_unseen_legs"] else []
    contig = None
    if frames is not None:
        from signsplat.fit.sequence import contiguous_triplets

        contig = torch.as_tensor(contiguous_triplets(np.asarray(frames)), device=device)
    return Problem(
        kpm=kpm, obs=obs_t,
        weights=obj.Weights.from_config({**cfg["weights"], **(weights or {})}),
        kernel=cfg["robust"]["kernel"], sigma_px=cfg["robust"]["sigma_px"], contiguous=contig,
        anchor={k: torch.as_tensor(v, dtype=dtype, device=device)
                for k, v in (anchor or {}).items()},
        pose_mean=obj.rest_pose_vector(cfg["rest_pose"], dtype=dtype, device=device),
        up=None if up is None else torch.as_tensor(up, dtype=dtype, device=device),
        level_cameras=bool(level_cameras and up is not None),
        silhouette=None if masks is None else targets_from_masks(masks, dtype=dtype,
                                                                 device=device),
        flow=flow, flow_settings={} if flow is None else dict(cfg["multiview"]["flow"]),
        held_pose=obj.held_pose_mask(legs, device=device) if legs else None,
        view_px=None if view_px is None else np.asarray(view_px, float))


def rest_body_pose(cfg: dict, T: int) -> np.ndarray:
    """(T,63) initial body pose: the config's rest pose (prior mean) for every frame."""
    return np.repeat(obj.rest_pose_vector(cfg["rest_pose"], torch.float64).numpy()[None],
                     T, axis=0)


def _pose_vector(params: FitParams, sel) -> torch.Tensor:
    return torch.cat([params.global_orient[sel], params.body_pose[sel], params.jaw_pose[sel],
                      params.left_free[sel] * 0.1, params.right_free[sel] * 0.1], dim=-1)


def loss_terms(problem: Problem, params: FitParams, cams: CameraParams, stage: Stage,
               sel: slice = slice(None), matches: MatchCache | None = None,
               flow_matches: MatchCache | None = None) -> dict[str, torch.Tensor]:
    """All loss terms of the frames ``sel`` (a slice of the sequence). ``matches`` and
    ``flow_matches``: the stage run's caches of the silhouette terms' contour matches and of
    the flow term's vertices (None: match every call)."""
    w = problem.weights
    dev, dt = params.transl.device, params.transl.dtype
    inputs = params.model_inputs(sel)
    sil = stage.uses_silhouette
    if sil and problem.silhouette is None:
        raise ValueError(f"stage {stage.name!r} weights the silhouette terms but no person "
                         "masks were given (fit --masks: the perception stage's masks table)")
    fl = stage.uses_flow
    if fl and problem.flow is None:
        raise ValueError(f"stage {stage.name!r} weights the flow term but no images were given "
                         "(fit --frames: the frames table with the images)")
    _, kp3d, body = problem.kpm(full=sil or fl, **inputs)
    K, R, t = cams()
    kpw = obj.part_weight_vector(stage.parts, dtype=dt, device=dev)
    sigma = problem.sigma_px if stage.sigma_px is None else stage.sigma_px
    data, behind = obj.reprojection(kp3d, K, R, t, problem.obs[:, sel], kpw, problem.kernel,
                                    sigma)
    terms = {"data": w.reprojection * data, "behind": w.behind_camera * behind}
    pose_w = obj.body_pose_weights(w, dtype=dt, device=dev)
    sub = _SubParams(params, sel)
    up = obj.level_rig_up(R) if problem.level_cameras else problem.up
    terms["prior"] = obj.priors(sub, w, pose_w, problem.pose_mean, up)
    if stage.smooth:
        contig = None if problem.contiguous is None else _contig(problem.contiguous, sel,
                                                                 kp3d.shape[0])
        terms["smooth"] = obj.smoothness(kp3d, _pose_vector(params, sel), contig, w)
    if w.camera_anchor > 0 and "cameras" in stage.groups:
        terms["camera_anchor"] = w.camera_anchor * (
            (cams.rotvec * cams.free) ** 2 + (cams.dt * cams.free) ** 2).sum()
    if problem.anchor:
        terms["anchor"] = obj.anchor(sub, {k: v[sel] for k, v in problem.anchor.items()}, w)
    if sil or fl:
        frames = torch.arange(problem.obs.shape[1], device=dev)[sel]
        projected = project(body.vertices, K, R, t)
    if sil:
        inside, cover = silhouette_terms(body.vertices, problem.kpm.model.faces, K, R, t,
                                         problem.silhouette, frames, cache=matches,
                                         projected=projected)
        terms["silhouette_inside"] = float(stage.silhouette.get("inside", 0.0)) * inside
        terms["silhouette_cover"] = float(stage.silhouette.get("cover", 0.0)) * cover
    if fl:
        terms["flow"] = stage.flow * flow_term(*projected, problem.flow, frames,
                                               problem.flow_settings["clamp_px"],
                                               cache=flow_matches,
                                               max_vertices=problem.flow_settings["max_vertices"])
    return terms


def _contig(contiguous: torch.Tensor, sel: slice, T: int) -> torch.Tensor:
    start = sel.start or 0
    return contiguous[start:start + max(T - 2, 0)]


class _SubParams:
    """View of :class:`FitParams` restricted to frames ``sel`` (for the prior terms)."""

    def __init__(self, params: FitParams, sel: slice):
        self._p, self._sel = params, sel
        self.betas = params.betas
        self.body_pose = params.body_pose[sel]
        self.expression = params.expression[sel]
        self.jaw_pose = params.jaw_pose[sel]
        self.global_orient = params.global_orient[sel]
        self.transl = params.transl[sel]
        self.num_frames = self.transl.shape[0]

    def hand_anatomical(self, side: str) -> torch.Tensor:
        return self._p.hand_anatomical(side, self._sel)


def _param_groups(params: FitParams, cams: CameraParams, stage: Stage) -> list[dict]:
    groups = params.groups()
    out = []
    for name in stage.groups:
        tensors = [cams.rotvec, cams.dt] + ([cams.log_focal] if cams.log_focal.requires_grad
                                            else []) if name == "cameras" else groups[name]
        out.append({"params": tensors, "lr": stage.lr * stage.lr_scale.get(name, 1.0),
                    "name": name})
    return out


def run_stage(problem: Problem, params: FitParams, cams: CameraParams, stage: Stage,
              sel: slice = slice(None)) -> list[float]:
    """Optimise ``stage.groups`` on frames ``sel`` with Adam + cosine decay; returns losses.
    The body-pose values of ``problem.held_pose`` get no gradient and end the stage at the
    prior mean, whatever the optimiser."""
    if stage.iterations <= 0:
        return []
    if stage.optimizer == "lm":
        from signsplat.fit.levenberg_marquardt import run_lm

        history = run_lm(problem, params, cams, stage, sel)
    else:
        groups = _param_groups(params, cams, stage)
        history = (_run_lbfgs(problem, params, cams, stage, sel, groups)
                   if stage.optimizer == "lbfgs" else
                   _run_adam(problem, params, cams, stage, sel, groups))
    if problem.held_pose is not None:
        mean = (problem.pose_mean if problem.pose_mean is not None else
                torch.zeros_like(params.body_pose[0]))
        with torch.no_grad():
            params.body_pose[:, problem.held_pose] = mean[problem.held_pose].to(
                params.body_pose.dtype)
    return history


def _run_adam(problem: Problem, params: FitParams, cams: CameraParams, stage: Stage,
              sel: slice, groups: list[dict]) -> list[float]:
    opt = torch.optim.Adam(groups)
    held = problem.held_views(stage)
    base = [g["lr"] for g in opt.param_groups]
    history: list[float] = []
    cache = MatchCache(stage.rematch_every)
    flow_cache = MatchCache(stage.flow_rematch_every or stage.rematch_every)
    for it in range(stage.iterations):
        frac = it / max(stage.iterations - 1, 1)
        scale = stage.final_lr_fraction + (1 - stage.final_lr_fraction) * 0.5 * (
            1 + math.cos(math.pi * frac))
        for g, b in zip(opt.param_groups, base):
            g["lr"] = b * scale
        opt.zero_grad(set_to_none=True)
        terms = loss_terms(problem, params, cams, stage, sel, cache, flow_cache)
        loss = sum(terms.values())
        if not torch.isfinite(loss):
            raise FloatingPointError(f"stage {stage.name}: non-finite loss at iteration {it} "
                                     f"({ {k: float(v) for k, v in terms.items()} })")
        loss.backward()
        _sanitize_grads([p for g in opt.param_groups for p in g["params"]], problem, params,
                        cams, held)
        opt.step()
        history.append(float(loss.detach()))
    log.debug("stage %s terms: %s", stage.name,
              {k: round(float(v.detach()), 3) for k, v in terms.items()})
    log.debug("stage %s: loss %.4g -> %.4g", stage.name, history[0], history[-1])
    return history


def _sanitize_grads(tensors, problem: Problem, params: FitParams,
                    cams: CameraParams | None = None, held_views: list[int] = ()) -> None:
    """A non-finite gradient must never reach the parameters, nor any to a held pose value
    or to a held view's camera (``held_views`` of ``cams``)."""
    for p in tensors:
        if p.grad is not None:
            torch.nan_to_num_(p.grad, nan=0.0, posinf=0.0, neginf=0.0)
    if problem.held_pose is not None and params.body_pose.grad is not None:
        params.body_pose.grad[:, problem.held_pose] = 0.0
    if cams is not None and held_views:
        for p in (cams.rotvec, cams.dt, cams.log_focal):
            if p.grad is not None:
                p.grad[list(held_views)] = 0.0


def _run_lbfgs(problem: Problem, params: FitParams, cams: CameraParams, stage: Stage,
               sel: slice, groups: list[dict]) -> list[float]:
    """L-BFGS with a strong-Wolfe line search over all of the stage's tensors (one group;
    ``lr_scale`` rescales nothing here). ``iterations`` bounds the L-BFGS iterations."""
    tensors = [p for g in groups for p in g["params"]]
    opt = torch.optim.LBFGS(tensors, lr=stage.lr, max_iter=stage.iterations,
                            max_eval=int(stage.iterations * 1.25) + 1, history_size=30,
                            tolerance_grad=1e-10, tolerance_change=1e-12,
                            line_search_fn="strong_wolfe")
    held = problem.held_views(stage)
    history: list[float] = []

    def closure():
        opt.zero_grad(set_to_none=True)
        terms = loss_terms(problem, params, cams, stage, sel)
        loss = sum(terms.values())
        if not torch.isfinite(loss):
            raise FloatingPointError(f"stage {stage.name}: non-finite loss")
        loss.backward()
        _sanitize_grads(tensors, problem, params, cams, held)
        history.append(float(loss.detach()))
        return loss

    opt.step(closure)
    log.debug("stage %s (lbfgs): %d evaluations, loss %.6g -> %.6g", stage.name, len(history),
              history[0] if history else float("nan"), history[-1] if history else float("nan"))
    return history


def copy_frame(params: FitParams, src: int, dst: slice, groups) -> None:
    """Warm start: copy the per-frame blocks of the parameter ``groups`` (names of
    :meth:`FitParams.groups`) of frame ``src`` into frames ``dst``. The betas, shared by every
    frame, and the cameras, which are not per frame, are never copied."""
    blocks = params.groups()
    with torch.no_grad():
        for group in groups:
            if group == "betas":
                continue
            for p in blocks.get(group, ()):
                p[dst] = p[src]


def run_warm_started(problem: Problem, params: FitParams, cams: CameraParams, stage: Stage,
                     chunk: int, valid: np.ndarray | None = None,
                     solved: frozenset[str] | set[str] = frozenset()) -> list[float]:
    """Run ``stage`` chunk by chunk; chunk k starts from the last frame solved in chunk k-1.

    ``valid (T,)`` bool marks frames with observations; the warm start copies the last valid
    frame. Only the stage's groups that no earlier stage has solved (``solved``: group names)
    are copied: a block an earlier stage fitted frame by frame keeps its own values (copying
    it would replace a moving signer's root by the previous chunk's). Returns the final loss
    of each chunk.
    """
    T = params.num_frames
    chunk = max(int(chunk), 1)
    fresh = [g for g in stage.groups if g not in solved]
    finals = []
    last_valid = None
    for start in range(0, T, chunk):
        stop = min(start + chunk, T)
        if last_valid is not None and fresh:
            copy_frame(params, last_valid, slice(start, stop), fresh)
        hist = run_stage(problem, params, cams, stage, slice(start, stop))
        finals.append(hist[-1] if hist else float("nan"))
        idx = np.arange(start, stop)
        if valid is not None:
            idx = idx[valid[start:stop]]
        if len(idx):
            last_valid = int(idx[-1])
    return finals
