"""Effect registry: a scene lists the effects it wants, and only those are built and run.

Each effect is a class registered under a name with a set of validated options and exactly one
*hook*, the point of the simulation pipeline where it acts:

========== ======================================================= ============================
hook       called as                                               effects
========== ======================================================= ============================
camera     ``camera(cam, view, frame) -> Camera``                  camera_jitter
subframes  ``subframes() -> (offsets (S,), weights (S,))``         motion_blur
geometry   ``geometry(cam, view, frame, target) -> list[Prop]``    occluder
shade      ``shade(albedo, normals, points, cam) -> (P, 3)``       lighting
background ``background(view, frame, height, width) -> (H, W, 3)`` background
image      ``image(rgb, view, frame) -> (H, W, 3)``                sensor_noise
========== ======================================================= ============================

:func:`build_effects` turns a scene's ``effects`` list into an :class:`EffectChain` holding
instances of the listed classes only; the simulator asks the chain for the effects of a hook
and calls nothing when the list is empty. Without any effect a render is the unlit albedo
over a black background, with static cameras and an instantaneous shutter.

Randomness is seeded per effect, view and frame (:meth:`Effect.rng`), so an effect's output
does not depend on which other effects run or in which order frames are rendered.
"""

from __future__ import annotations

import zlib
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, replace
from typing import Any, ClassVar

import numpy as np

from signsplat.errors import SignSplatError

HOOKS = ("camera", "subframes", "geometry", "shade", "background", "image")


class EffectError(SignSplatError, ValueError):
    """An effect name or option in a scene is not known or not allowed."""


@dataclass(frozen=True)
class Camera:
    """A pinhole camera (OpenCV): ``K`` (3,3) pixels, ``R`` (3,3), ``t`` (3,) metres."""

    K: np.ndarray
    R: np.ndarray
    t: np.ndarray
    width: int
    height: int

    @property
    def center(self) -> np.ndarray:
        """(3,) camera centre in world coordinates (metres)."""
        return -self.R.T @ self.t


@dataclass(frozen=True)
class Prop:
    """Extra scene geometry (not the signer): a triangle mesh with one RGB colour in [0, 1]."""

    vertices: np.ndarray  # (V, 3) float64 world metres
    faces: np.ndarray  # (F, 3) int64
    color: np.ndarray  # (3,) float32


# --- options -----------------------------------------------------------------------------

@dataclass(frozen=True)
class Option:
    """One effect option: its default, a check, and a description of what is allowed."""

    default: Any
    check: Callable[[Any], bool]
    allowed: str


def _is_num(x) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool) and np.isfinite(x)


def number(lo: float | None = None, hi: float | None = None, default: float = 0.0) -> Option:
    desc = "a number" + (f" >= {lo}" if lo is not None else "") + (
        f" and <= {hi}" if hi is not None else "")
    return Option(default, lambda x: _is_num(x) and (lo is None or x >= lo)
                  and (hi is None or x <= hi), desc)


def integer(lo: int | None = None, default: int = 0, nullable: bool = False) -> Option:
    desc = "an integer" + (f" >= {lo}" if lo is not None else "") + (" or null" if nullable else "")
    return Option(default, lambda x: (nullable and x is None) or (
        isinstance(x, int) and not isinstance(x, bool) and (lo is None or x >= lo)), desc)


def vector(n: int, default, lo: float | None = None, hi: float | None = None) -> Option:
    desc = f"a list of {n} numbers" + (f" in [{lo}, {hi}]" if lo is not None else "")
    return Option(tuple(default), lambda x: isinstance(x, (list, tuple)) and len(x) == n and all(
        _is_num(v) and (lo is None or v >= lo) and (hi is None or v <= hi) for v in x), desc)


def choice(values: Iterable[str], default: str) -> Option:
    values = tuple(values)
    return Option(default, lambda x: x in values, "one of " + ", ".join(map(repr, values)))


def int_list(default) -> Option:
    return Option(tuple(default), lambda x: isinstance(x, (list, tuple)) and all(
        isinstance(v, int) and not isinstance(v, bool) and v >= 0 for v in x),
        "a list of integers >= 0")


# --- base class and registry --------------------------------------------------------------

class Effect:
    """Base class. Subclasses set ``name``, ``hook`` (one of :data:`HOOKS`), ``OPTIONS``.

    Built as ``cls(scene_seed, **options)``; ``self.options`` holds the validated options
    (defaults filled in), ``self.seed`` the scene seed.
    """

    name: ClassVar[str] = ""
    hook: ClassVar[str] = ""
    OPTIONS: ClassVar[dict[str, Option]] = {}

    def __init__(self, scene_seed: int = 0, /, **options: Any) -> None:
        self.seed = int(scene_seed)
        self.options = validate_options(type(self), options)

    def rng(self, view: int, frame: int) -> np.random.Generator:
        """Generator seeded by (scene seed, effect name, view, frame)."""
        key = zlib.crc32(self.name.encode())
        return np.random.default_rng([self.seed, key, view + 1, frame + 1])

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.options})"


REGISTRY: dict[str, type[Effect]] = {}


def register(cls: type[Effect]) -> type[Effect]:
    """Class decorator adding an effect to :data:`REGISTRY` under ``cls.name``."""
    if cls.hook not in HOOKS:
        raise ValueError(f"effect {cls.name!r}: hook {cls.hook!r} is not one of {HOOKS}")
    if not callable(getattr(cls, cls.hook, None)):
        raise ValueError(f"effect {cls.name!r} does not define its hook method {cls.hook!r}")
    REGISTRY[cls.name] = cls
    return cls


def validate_options(cls: type[Effect], options: Mapping[str, Any]) -> dict[str, Any]:
    """Check ``options`` against ``cls.OPTIONS`` and fill defaults; errors name the option."""
    unknown = [k for k in options if k not in cls.OPTIONS]
    if unknown:
        raise EffectError(f"effect '{cls.name}': unknown option(s) {unknown}; allowed options: "
                          + ", ".join(sorted(cls.OPTIONS)))
    out = {}
    for key, opt in cls.OPTIONS.items():
        value = options.get(key, opt.default)
        if key in options and not opt.check(value):
            raise EffectError(f"effect '{cls.name}': option '{key}' = {value!r} is not allowed; "
                              f"must be {opt.allowed}")
        out[key] = value
    return out


def parse_effect_list(entries: Iterable[Any]) -> list[tuple[str, dict[str, Any]]]:
    """Normalise a scene's ``effects`` list to ``[(name, options), ...]`` and check names.

    Each entry is a name (``"lighting"``) or a one-key mapping (``{"lighting": {...}}``).
    """
    parsed = []
    for entry in entries:
        if isinstance(entry, str):
            name, opts = entry, {}
        elif isinstance(entry, Mapping) and len(entry) == 1:
            name, opts = next(iter(entry.items()))
            opts = {} if opts is None else opts
            if not isinstance(opts, Mapping):
                raise EffectError(f"effect '{name}': options must be a mapping, got {opts!r}")
        else:
            raise EffectError(f"effects: entry {entry!r} must be a name or a one-key mapping "
                              "{name: {options}}")
        if name not in REGISTRY:
            raise EffectError(f"unknown effect {name!r}; known effects: "
                              + ", ".join(sorted(REGISTRY)))
        if any(name == n for n, _ in parsed):
            raise EffectError(f"effect '{name}' is listed twice")
        parsed.append((name, dict(opts)))
    return parsed


class EffectChain:
    """The instantiated effects of one scene, grouped by hook in the scene's order."""

    def __init__(self, effects: Iterable[Effect]) -> None:
        self.effects = tuple(effects)
        self._by_hook = {h: tuple(e for e in self.effects if e.hook == h) for h in HOOKS}

    def at(self, hook: str) -> tuple[Effect, ...]:
        """Effects acting at ``hook`` (an empty tuple when the scene lists none)."""
        return self._by_hook[hook]

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(e.name for e in self.effects)

    def __contains__(self, name: str) -> bool:
        return name in self.names


def build_effects(entries: Iterable[Any], seed: int = 0) -> EffectChain:
    """Instantiate exactly the effects a scene lists (validated); nothing else is built."""
    return EffectChain(REGISTRY[name](seed, **opts) for name, opts in parse_effect_list(entries))


# --- the effects ---------------------------------------------------------------------------

@register
class Lighting(Effect):
    """Lambertian shading with an ambient term: ``albedo * (ambient + intensity * max(n.l, 0))``.

    Normals are turned to face the camera (two-sided surfaces). ``direction`` points from the
    scene towards the light (world frame, normalised here).
    """

    name = "lighting"
    hook = "shade"
    OPTIONS = {
        "direction": vector(3, (0.3, 0.6, 1.0)),
        "ambient": number(0.0, 1.0, 0.35),
        "intensity": number(0.0, 10.0, 0.75),
        "color": vector(3, (1.0, 1.0, 1.0), 0.0, 10.0),
    }

    def __init__(self, scene_seed: int = 0, /, **options: Any) -> None:
        super().__init__(scene_seed, **options)
        d = np.asarray(self.options["direction"], np.float64)
        if np.linalg.norm(d) < 1e-9:
            raise EffectError("effect 'lighting': option 'direction' must be a non-zero vector")
        self._dir = (d / np.linalg.norm(d)).astype(np.float32)
        self._color = np.asarray(self.options["color"], np.float32)

    def shade(self, albedo: np.ndarray, normals: np.ndarray, points: np.ndarray,
              cam: Camera) -> np.ndarray:
        """albedo (P,3) [0,1], normals (P,3) world, points (P,3) world -> (P,3) float32."""
        to_cam = cam.center.astype(np.float32)[None] - points
        flip = np.sign(np.einsum("pc,pc->p", normals, to_cam))
        flip[flip == 0] = 1.0
        lambert = np.clip(np.einsum("pc,c->p", normals * flip[:, None], self._dir), 0.0, None)
        gain = self.options["ambient"] + self.options["intensity"] * lambert
        return (albedo * gain[:, None] * self._color[None]).astype(np.float32)


@register
class Background(Effect):
    """Fill the uncovered pixels: a solid colour or a procedural texture (per view, static).

    ``textured``: smooth value noise tinted between two colours plus faint stripes, seeded by
    ``seed`` and the view, constant over frames (a static studio wall).
    """

    name = "background"
    hook = "background"
    OPTIONS = {
        "kind": choice(("solid", "textured"), "solid"),
        "color": vector(3, (0.5, 0.5, 0.5), 0.0, 1.0),
        "color2": vector(3, (0.25, 0.3, 0.35), 0.0, 1.0),
        "seed": integer(0, 0),
        "scale": number(1e-3, None, 24.0),
    }

    def __init__(self, scene_seed: int = 0, /, **options: Any) -> None:
        super().__init__(scene_seed, **options)
        self._cache: dict[tuple[int, int, int], np.ndarray] = {}

    def background(self, view: int, frame: int, height: int, width: int) -> np.ndarray:
        """(H, W, 3) float32 in [0, 1]."""
        key = (view, height, width)
        if key not in self._cache:
            self._cache[key] = self._make(view, height, width)
        return self._cache[key]

    def _make(self, view: int, height: int, width: int) -> np.ndarray:
        c1 = np.asarray(self.options["color"], np.float32)
        if self.options["kind"] == "solid":
            return np.broadcast_to(c1, (height, width, 3))
        c2 = np.asarray(self.options["color2"], np.float32)
        rng = np.random.default_rng([self.options["seed"], view + 1])
        scale = float(self.options["scale"])
        gh, gw = int(np.ceil(height / scale)) + 2, int(np.ceil(width / scale)) + 2
        noise = np.zeros((height, width), np.float32)
        for octave, amp in ((1, 0.6), (2, 0.3), (4, 0.1)):
            grid = rng.random((gh * octave, gw * octave)).astype(np.float32)
            noise += amp * _bilinear_upsample(grid, height, width, scale / octave)
        yy, xx = np.mgrid[0:height, 0:width].astype(np.float32)
        stripes = 0.08 * np.sin((xx * 0.8 + yy * 0.3) * (2 * np.pi / scale))
        mix = np.clip(noise + stripes, 0.0, 1.0)[..., None]
        return (c1 * (1 - mix) + c2 * mix).astype(np.float32)


def _bilinear_upsample(grid: np.ndarray, height: int, width: int, cell: float) -> np.ndarray:
    """Sample a coarse (h, w) grid with cell size ``cell`` pixels at every pixel, smoothly."""
    ys = np.arange(height, dtype=np.float32) / cell
    xs = np.arange(width, dtype=np.float32) / cell
    y0, x0 = np.floor(ys).astype(int), np.floor(xs).astype(int)
    fy, fx = ys - y0, xs - x0
    fy, fx = fy * fy * (3 - 2 * fy), fx * fx * (3 - 2 * fx)  # smoothstep
    a = grid[np.ix_(y0, x0)]
    b = grid[np.ix_(y0, x0 + 1)]
    c = grid[np.ix_(y0 + 1, x0)]
    d = grid[np.ix_(y0 + 1, x0 + 1)]
    top = a * (1 - fx)[None] + b * fx[None]
    bottom = c * (1 - fx)[None] + d * fx[None]
    return top * (1 - fy)[:, None] + bottom * fy[:, None]


@register
class SensorNoise(Effect):
    """Additive Gaussian noise of standard deviation ``sigma`` (in [0, 1] intensity units)."""

    name = "sensor_noise"
    hook = "image"
    OPTIONS = {"sigma": number(0.0, 1.0, 0.01)}

    def image(self, rgb: np.ndarray, view: int, frame: int) -> np.ndarray:
        """(H, W, 3) float32 in [0, 1] -> noisy copy clipped to [0, 1]."""
        noise = self.rng(view, frame).standard_normal(rgb.shape, dtype=np.float32)
        return np.clip(rgb + np.float32(self.options["sigma"]) * noise, 0.0, 1.0)


@register
class MotionBlur(Effect):
    """Average ``samples`` renders at poses spread over ``shutter`` of a frame interval.

    Sub-frame offsets (in frames) are centred on the frame time; poses in between frames are
    interpolated by the simulator. The mask is the averaged coverage thresholded at 0.5.
    """

    name = "motion_blur"
    hook = "subframes"
    OPTIONS = {
        "samples": integer(2, 5),
        "shutter": number(0.0, 1.0, 0.5),
    }

    def subframes(self) -> tuple[np.ndarray, np.ndarray]:
        """Offsets (S,) float64 in frames, weights (S,) float64 summing to 1."""
        s = int(self.options["samples"])
        half = 0.5 * float(self.options["shutter"])
        offsets = np.linspace(-half, half, s)
        return offsets, np.full(s, 1.0 / s)


@register
class Occluder(Effect):
    """A coloured box between a camera and the signer for a range of frames.

    Placed on the line from the camera centre to the scene target at ``position`` (fraction of
    the distance from the camera), shifted by ``offset`` (metres, camera right/down), moving by
    ``sweep`` (metres per frame, camera right). It is drawn with the signer in one depth test,
    so the keypoints behind it become invisible. Applies to ``views`` and frames in
    ``[start, stop)`` (``stop`` null = to the end).
    """

    name = "occluder"
    hook = "geometry"
    OPTIONS = {
        "views": int_list((0,)),
        "start": integer(0, 0),
        "stop": integer(0, None, nullable=True),
        "size": vector(3, (0.2, 0.25, 0.02), 1e-4, 100.0),
        "position": number(0.05, 0.95, 0.5),
        "offset": vector(2, (0.0, 0.0)),
        "sweep": number(None, None, 0.0),
        "color": vector(3, (0.15, 0.35, 0.75), 0.0, 1.0),
    }

    def active(self, view: int, frame: int) -> bool:
        stop = self.options["stop"]
        return (view in self.options["views"] and frame >= self.options["start"]
                and (stop is None or frame < stop))

    def geometry(self, cam: Camera, view: int, frame: int, target: np.ndarray) -> list[Prop]:
        if not self.active(view, frame):
            return []
        c = cam.center
        centre = c + float(self.options["position"]) * (np.asarray(target, np.float64) - c)
        right, down = cam.R[0], cam.R[1]
        dx, dy = self.options["offset"]
        centre = centre + (dx + self.options["sweep"] * (frame - self.options["start"])) * right \
            + dy * down
        sx, sy, sz = (0.5 * float(v) for v in self.options["size"])
        corners = np.array([[x, y, z] for x in (-sx, sx) for y in (-sy, sy) for z in (-sz, sz)])
        # box axes aligned with the camera (right, down, forward)
        verts = centre[None] + corners @ cam.R
        faces = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                          [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]],
                         np.int64)
        return [Prop(verts, faces, np.asarray(self.options["color"], np.float32))]


@register
class CameraJitter(Effect):
    """Small random per-frame extrinsic perturbations (rotation and translation).

    With this effect the cameras table has one row per view and frame. The camera centre moves
    by N(0, ``translation``) metres per axis and the camera rotates by N(0, ``rotation_deg``)
    degrees about each of its axes.
    """

    name = "camera_jitter"
    hook = "camera"
    OPTIONS = {
        "rotation_deg": number(0.0, 45.0, 0.3),
        "translation": number(0.0, 1.0, 0.005),
    }

    def camera(self, cam: Camera, view: int, frame: int) -> Camera:
        rng = self.rng(view, frame)
        rotvec = np.deg2rad(float(self.options["rotation_deg"])) * rng.standard_normal(3)
        dc = float(self.options["translation"]) * rng.standard_normal(3)
        dR = _rodrigues(rotvec)
        R = dR @ cam.R
        center = cam.center + dc
        return replace(cam, R=R, t=-R @ center)


def _rodrigues(rotvec: np.ndarray) -> np.ndarray:
    """(3,) axis-angle -> (3, 3) rotation matrix."""
    theta = float(np.linalg.norm(rotvec))
    if theta < 1e-12:
        return np.eye(3)
    k = rotvec / theta
    Kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(theta) * Kx + (1 - np.cos(theta)) * Kx @ Kx
