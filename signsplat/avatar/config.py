"""Avatar configuration: dataclasses filled from the validated ``avatar`` YAML section.

The schema (``workflow/schemas/stages/avatar.schema.yaml``) owns names, types, ranges and the
``demo`` defaults; :data:`PROFILES` holds the overrides of the other named profiles. A config
dict is resolved as: schema defaults <- profile overrides <- the user's explicit values.
Nothing here is global state: :func:`avatar_config` returns a fresh :class:`AvatarConfig`.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, field, fields, is_dataclass
from typing import Any

from signsplat.config import validate

SCHEMA = "stages/avatar.schema.yaml"

# Overrides applied on top of the schema defaults (which are the ``demo`` profile).
PROFILES: dict[str, dict[str, Any]] = {
    "demo": {},
    "quality": {
        "upsample": {"edge_length": 0.008, "face_area": 3.0e-5},
        "train": {"iterations": 6000, "accumulate_poses": 4},
        "model": {"sh_degree": 1, "hidden": 48},
        "strategy": {"refine_start": 300, "refine_every": 100, "refine_stop": 4500,
                     "max_points": 200000},
        "sh_schedule": {"rise_at": 0.8},
    },
}


@dataclass
class UpsampleConfig:
    edge_length: float = 0.012  # m; edges longer than this get points along them
    face_area: float = 6.0e-5  # m^2; faces larger than this get a point at their centre
    max_rounds: int = 1
    interior: str = "grid"  # large faces: "centre" (the paper's centroid) or a barycentric grid


@dataclass
class PartValues:
    body: float
    head: float
    hands: float


@dataclass
class ModelConfig:
    pose_dependent: bool = True  # off = static mesh-anchored baseline (no Omega network)
    displacement: bool = True  # eq. 3 displacements of original vertices
    shading: bool = True  # learned global irradiance of the posed normal (see model docstring)
    hidden: int = 32
    kernel: int = 5
    layers: int = 2
    sh_degree: int = 1  # highest SH degree (reached late, see sh_schedule)
    scale_min: float = 2.0e-4  # m
    scale_max: PartValues = field(default_factory=lambda: PartValues(0.02, 0.008, 0.004))
    displacement_limit: PartValues = field(default_factory=lambda: PartValues(0.02, 0.01, 0.003))
    init_opacity: float = 0.9
    flat_init: float = 0.2  # > 0: start as discs in the surface, normal scale = this x in-plane
    init_color: tuple[float, float, float] = (0.5, 0.5, 0.5)


@dataclass
class ShSchedule:
    rise_at: float = 0.75  # fraction of iterations after which the SH degree steps up


@dataclass
class StrategyConfig:
    enabled: bool = True  # densification + pruning (paper Table 5 "Dens.")
    grad_threshold: float = 0.0002
    refine_start: int = 100
    refine_stop: int = 900
    refine_every: int = 50
    reset_every: int = 0  # 0 = never reset the gradient statistics except after refining
    max_points: int = 90000
    max_new_per_refine: int = 3000
    prune_opacity: float = 0.02
    prune_scale_fraction: float = 0.98  # of the per-part scale bound
    prune_keep_fraction: float = 0.5  # pruning by subsampling: this share of candidates stays
    seed: int = 0


@dataclass
class RegularizeConfig:
    enabled: bool = True  # neighbourhood variance terms (paper Table 5 "Reg.")
    radius: float = 0.03  # m
    max_neighbours: int = 8
    w_scale: float = 1.0
    w_rotation: float = 0.1
    w_opacity: float = 0.1
    w_color: float = 0.5
    w_sh_rest: float = 1.0
    w_displacement: float = 1.0  # penalty on squared displacement magnitude (m^2 -> scaled)
    w_normal_offset: float = 1.0


@dataclass
class LossConfig:
    w_l1: float = 0.8
    w_dssim: float = 0.2
    w_lpips: float = 0.0  # used only when lpips_weights is a local file
    w_hand: float = 0.5  # extra L1 on hand crops (SMPL-X projected hand joints)
    lpips_weights: str | None = None
    ssim_window: int = 11


@dataclass
class TrainConfig:
    iterations: int = 1200
    accumulate_poses: int = 3  # poses whose losses are summed before a step (Table 5 "Acc.")
    accumulate: bool = True  # off = one pose per optimiser step
    views_per_pose: int = 1  # cameras each sampled pose is rendered from (posing shared)
    lr_means: float = 1.0e-3  # learnable barycentric logits / normal offsets
    lr_scale: float = 5.0e-3
    lr_rotation: float = 1.0e-3
    lr_opacity: float = 2.5e-2
    lr_color: float = 2.5e-2
    lr_sh_rest: float = 1.25e-3
    lr_network: float = 1.0e-3
    lr_shading: float = 1.0e-2  # the 27 irradiance coefficients (model.shading)
    lr_final_fraction: float = 1.0  # every learning rate decays exponentially to this share
    color_init: str = "images"  # "images": median observed colour per point; "constant"
    color_init_images: int = 24  # training images sampled for it
    finetune_smplx: bool = True
    lr_smplx: float = 1.0e-4
    lr_betas: float | None = 1.0e-2  # the shared shape coefficients; None = lr_smplx
    refine_cameras: bool | str = "auto"  # true, false or "auto" (on for fitted cameras)
    lr_cameras: float = 1.0e-3  # rad and m per step (Adam) of the camera corrections
    refine_cameras_stop: int = 300  # step after which the corrections stay fixed; 0 = never
    test_interval: int = 10  # every test_interval-th frame is held out (novel pose)
    test_offset: int = 5
    test_views: list[int] = field(default_factory=list)  # held-out cameras (novel view)
    background: tuple[float, float, float] = (1.0, 1.0, 1.0)
    resolution: int = 0  # 0 = native; otherwise images are resized to this square size
    checkpoint_every: int = 250
    log_every: int = 10
    seed: int = 0
    threads: int = 2
    render_backend: str = "auto"
    ply_frame: int = -1  # -1 = export the canonical rest pose; otherwise this frame's pose
    smplx_source: str = "fitted"


@dataclass
class EvalConfig:
    refine_steps: int = 60  # test-time pose refinement iterations per held-out frame
    refine_lr: float = 2.0e-3
    crop_size: PartValues = field(default_factory=lambda: PartValues(0.0, 0.2, 0.15))
    far_view_degrees: float = 25.0
    save_images: int = 6
    max_frames: int = 0  # 0 = every held-out frame


# EvalConfig fields the trainer never reads (crop_size it does: the hand loss); the workflow
# leaves them out of the training rule's params
EVAL_ONLY_KEYS = ("refine_steps", "refine_lr", "far_view_degrees", "save_images", "max_frames")


@dataclass
class AvatarConfig:
    profile: str = "demo"
    upsample: UpsampleConfig = field(default_factory=UpsampleConfig)
    model: ModelConfig = field(default_factory=ModelConfig)
    sh_schedule: ShSchedule = field(default_factory=ShSchedule)
    strategy: StrategyConfig = field(default_factory=StrategyConfig)
    regularize: RegularizeConfig = field(default_factory=RegularizeConfig)
    loss: LossConfig = field(default_factory=LossConfig)
    train: TrainConfig = field(default_factory=TrainConfig)
    eval: EvalConfig = field(default_factory=EvalConfig)


def _merge(base: dict, over: dict) -> dict:
    out = copy.deepcopy(base)
    for k, v in over.items():
        if isinstance(v, dict) and isinstance(out.get(k), dict):
            out[k] = _merge(out[k], v)
        else:
            out[k] = copy.deepcopy(v)
    return out


def _build(cls, data: dict):
    kwargs = {}
    for f in fields(cls):
        if f.name not in data:
            continue
        value = data[f.name]
        default = cls.__dataclass_fields__[f.name]
        proto = default.default_factory() if callable(default.default_factory) else None
        if is_dataclass(proto) and isinstance(value, dict):
            value = _build(type(proto), value)
        elif isinstance(proto, tuple) and isinstance(value, list):
            value = tuple(value)
        elif isinstance(default.default, tuple) and isinstance(value, list):
            value = tuple(value)
        kwargs[f.name] = value
    return cls(**kwargs)


def resolve(data: dict | None, source: str = "<avatar config>") -> dict:
    """Apply the chosen profile under the user's values, validate, fill defaults."""
    data = copy.deepcopy(data or {})
    profile = data.get("profile", "demo")
    validate(copy.deepcopy(data), SCHEMA, source)  # names the bad key before merging
    merged = _merge(PROFILES.get(profile, {}), data)
    merged["profile"] = profile
    return validate(merged, SCHEMA, source)


def avatar_config(data: dict | None = None, source: str = "<avatar config>") -> AvatarConfig:
    """The :class:`AvatarConfig` for an ``avatar`` config section (profile applied)."""
    return _build(AvatarConfig, resolve(data, source))


def to_dict(cfg: Any) -> Any:
    """Plain-data copy of a config dataclass (for checkpoints and logs)."""
    if is_dataclass(cfg):
        return {f.name: to_dict(getattr(cfg, f.name)) for f in fields(cfg)}
    if isinstance(cfg, tuple):
        return list(cfg)
    return cfg
