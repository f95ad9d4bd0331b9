"""Avatar configuration: dataclasses filled from the validated ``avatar`` YAML section.

The schema (``workflow/schemas/stages/avatar.schema.yaml``) owns names, types, ranges and the
``demo`` defaults; :data:`PROFILES` holds the overrides of the other named profiles. A config
dict is resolved as: schema defaults <- profile overrides <- the user's explicit values.
The dataclasses carry no defaults of their own (the schema's are the only copy), so an
:class:`AvatarConfig` comes from :func:`avatar_config`, which returns a fresh one each call:
nothing here is global state.
"""

from __future__ import annotations

from dataclasses import dataclass, fields, is_dataclass
from typing import Any, get_origin, get_type_hints

from signsplat.config import deep_merge, validate

SCHEMA = "stages/avatar.schema.yaml"

# Overrides applied on top of the schema defaults (which are the ``demo`` profile).
PROFILES: dict[str, dict[str, Any]] = {
    "demo": {},
    # The demo's settings trained longer with a higher point cap and learning rates decaying
    # to a tenth; densification stops at step 1800 and the SH degree rises at 2100; the poses
    # fine-tuned at the rate, and frame by frame, as its figures were measured (docs/avatar.md,
    # "The quality profile").
    "quality": {
        "train": {"iterations": 5600, "lr_final_fraction": 0.1, "lr_smplx": 1.0e-4,
                  "pose_knot_spacing": 1},
        "strategy": {"refine_stop": 1800, "max_points": 90000},
        "sh_schedule": {"rise_at": 0.375},
    },
}


@dataclass
class UpsampleConfig:
    edge_length: float  # m; edges longer than this get points along them
    face_area: float  # m^2; faces larger than this get a point at their centre
    max_rounds: int
    interior: str  # large faces: "centre" (the paper's centroid) or a barycentric grid


@dataclass
class PartValues:
    body: float
    head: float
    hands: float


@dataclass
class ModelConfig:
    pose_dependent: bool  # off = static mesh-anchored baseline (no Omega network)
    pose_net_on: str  # Omega runs over the "vertices" (interpolated to the points) or "points"
    displacement: bool  # eq. 3 displacements of original vertices
    shading: bool  # learned global irradiance of the posed normal (see model docstring)
    hidden: int
    kernel: int
    layers: int
    sh_degree: int  # highest SH degree (reached late, see sh_schedule)
    scale_min: float  # m
    scale_max: PartValues
    displacement_limit: PartValues
    init_opacity: float
    flat_init: float  # > 0: start as discs in the surface, normal scale = this x in-plane
    init_color: tuple[float, float, float]
    eps2d: float  # px^2, the rasterizer's 2D dilation in training and rendering
    rasterize_mode: str  # "classic" or "antialiased" (opacity compensated for the dilation)

    def raster_options(self) -> dict:
        """The rasterizer's options of every image render of the avatar (its filter)."""
        return {"eps2d": self.eps2d, "rasterize_mode": self.rasterize_mode}


@dataclass
class ShSchedule:
    rise_at: float  # fraction of iterations after which the SH degree steps up


@dataclass
class StrategyConfig:
    enabled: bool  # densification + pruning (paper Table 5 "Dens.")
    grad_threshold: float
    refine_start: int
    refine_stop: int
    refine_every: int
    reset_every: int  # 0 = never reset the gradient statistics except after refining
    max_points: int
    max_new_per_refine: int
    prune_opacity: float
    prune_scale_fraction: float  # of the per-part scale bound
    prune_keep_fraction: float  # pruning by subsampling: this share of candidates stays
    seed: int


@dataclass
class PartWeights:
    body: float
    face: float
    hands: float


@dataclass
class RegularizeConfig:
    enabled: bool  # neighbourhood variance terms (paper Table 5 "Reg.")
    radius: float  # m, in the space of position and scaled attributes
    max_neighbours: int
    attribute_scale: float  # m per unit of attribute difference; 0 = proximity only
    similarity: tuple[str, ...]  # attributes that count in the distance
    face_apart: bool  # head points never neighbours of body/hand points
    part_weights: PartWeights  # weight of each point's variance term by its part
    w_scale: float
    w_rotation: float
    w_opacity: float
    w_color: float
    w_sh_rest: float
    w_displacement: float  # penalty on squared displacement magnitude (m^2 -> scaled)
    w_normal_offset: float


@dataclass
class LossConfig:
    w_l1: float
    w_dssim: float
    w_lpips: float  # used only when lpips_weights is a local file
    w_hand: float  # extra L1 on hand crops (SMPL-X projected hand joints)
    lpips_weights: str | None
    ssim_window: int


@dataclass
class TrainConfig:
    iterations: int
    accumulate_poses: int  # poses whose losses are summed before a step (Table 5 "Acc.")
    accumulate: bool  # off = one pose per optimiser step
    views_per_pose: int  # cameras each sampled pose is rendered from (posing shared)
    lr_means: float  # learnable barycentric logits / normal offsets
    lr_scale: float
    lr_rotation: float
    lr_opacity: float
    lr_color: float
    lr_sh_rest: float
    lr_network: float
    lr_shading: float  # the 27 irradiance coefficients (model.shading)
    lr_final_fraction: float  # every learning rate decays exponentially to this share
    color_init: str  # "images": median observed colour per point; "constant"
    color_init_images: int  # training images sampled for it
    finetune_smplx: bool
    lr_smplx: float
    lr_betas: float | None  # the shared shape coefficients; None = lr_smplx
    lr_hand_poses: float | None  # the per-frame finger poses; None = lr_smplx
    pose_knot_spacing: int  # frames between knots of the poses' corrections; 1 = per frame
    refine_cameras: bool | str  # true, false or "auto" (on for fitted cameras)
    lr_cameras: float  # rad and m per step (Adam) of the camera corrections
    refine_cameras_stop: int  # step after which the corrections stay fixed; 0 = never
    test_interval: int  # every test_interval-th frame is held out (novel pose)
    test_offset: int
    test_views: list[int]  # held-out cameras (novel view)
    background: tuple[float, float, float]
    resolution: int  # 0 = native; otherwise images are resized to this square size
    checkpoint_every: int
    log_every: int
    seed: int
    render_backend: str
    ply_frame: int  # -1 = export the canonical rest pose; otherwise this frame's pose
    smplx_source: str


@dataclass
class EvalConfig:
    refine_steps: int  # test-time pose refinement iterations per held-out frame
    refine_lr: float
    refine_decay: str  # "constant" or "cosine" (down to 0 over refine_steps)
    heldout_pose: str  # "fit" or "interpolated" (training frames' corrections carried over)
    crop_size: PartValues
    far_view_degrees: float
    save_images: int
    max_frames: int  # 0 = every held-out frame


# EvalConfig fields the trainer never reads (crop_size it does: the hand loss); the workflow
# leaves them out of the training rule's params
EVAL_ONLY_KEYS = ("refine_steps", "refine_lr", "refine_decay", "heldout_pose", "far_view_degrees",
                  "save_images", "max_frames")


@dataclass
class AvatarConfig:
    profile: str
    upsample: UpsampleConfig
    model: ModelConfig
    sh_schedule: ShSchedule
    strategy: StrategyConfig
    regularize: RegularizeConfig
    loss: LossConfig
    train: TrainConfig
    eval: EvalConfig


def _build(cls, data: dict):
    """``cls`` from a resolved dict (every field present: the schema filled the defaults)."""
    hints = get_type_hints(cls)
    kwargs = {}
    for f in fields(cls):
        if f.name not in data:
            raise KeyError(f"avatar config: {cls.__name__}.{f.name} has no value and the schema "
                           f"{SCHEMA} gives it no default")
        value, hint = data[f.name], hints[f.name]
        if is_dataclass(hint) and isinstance(value, dict):
            value = _build(hint, value)
        elif get_origin(hint) is tuple and isinstance(value, list):
            value = tuple(value)
        kwargs[f.name] = value
    return cls(**kwargs)


def resolve(data: dict | None, source: str = "<avatar config>") -> dict:
    """Apply the chosen profile under the user's values, validate, fill defaults."""
    data = data or {}
    profile = data.get("profile", "demo")
    merged = deep_merge(PROFILES.get(profile, {}), data)  # the user's values win
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
