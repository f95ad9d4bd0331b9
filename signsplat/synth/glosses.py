"""The synthetic gloss library: short SMPL-X tracks of signs and of a fingerspelling alphabet.

Each gloss is built from phonological components (:mod:`signsplat.synth._gloss_signs`):
handshapes (named anatomical finger angles inside the hand joint limits,
:mod:`signsplat.synth._gloss_shapes`), locations on a standard skeleton, palm/finger
orientations, movements (tap, arc, circle, twist, move away/towards, repeat, shake) and
non-manual features (head nod/shake, brows, mouth via ``expression`` and ``jaw_pose``). Arm
poses that put the hand's contact point at a location come from an analytic two-bone IK
(:mod:`signsplat.synth._gloss_body`): closed form, so the library is deterministic and the whole
library builds in about a second.

Output: the ``gloss_library`` table (:mod:`signsplat.io.tables`), one row per gloss with the
per-frame blocks flattened into list columns. Hand poses are stored 'flat' (full rotation, no
MANO mean). ``global_orient``/``transl`` are not stored (identity / zero: the signer stands at
the origin facing +z); betas are not part of a gloss.
"""

from __future__ import annotations

import json
import os
import zlib
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np
import pandas as pd
from scipy.spatial.transform import Rotation

from signsplat.io.tables import write_table
from signsplat.synth import _gloss_body as gb
from signsplat.synth._gloss_shapes import angles_to_pose, handshape_angles
from signsplat.synth._gloss_signs import (
    LETTERS,
    REST,
    SIGNS,
    Hand,
    Move,
    Sign,
    letter_sign,
)

#: Meaning of the expression coefficients the library drives (index into ``expression``).
#: The proxy's expression directions (``signsplat.body._proxy_rig.EXPRESSION_NAMES``) use the
#: same indices; for a real SMPL-X model the PCA directions differ and these are only small
#: plausible offsets.
EXPRESSION_INDEX = {"jaw_open": 0, "smile": 1, "brow_raise": 2, "brow_furrow": 3,
                    "eyes_close": 4, "cheek_puff": 5, "lip_round": 6, "frown": 9}
DOMINANT = "right"
SOURCE = "signsplat.synth.glosses (procedural)"
LICENCE = "CC0-1.0"


# --- time and movement --------------------------------------------------------------------

def ease(t: np.ndarray) -> np.ndarray:
    """Cubic ease-in/ease-out ``3t^2 - 2t^3`` on [0, 1]."""
    t = np.clip(t, 0.0, 1.0)
    return t * t * (3.0 - 2.0 * t)


def _perp(d: np.ndarray) -> np.ndarray:
    a = np.array([0.0, 1.0, 0.0]) if abs(d[1]) < 0.9 else np.array([1.0, 0.0, 0.0])
    u = np.cross(d, a)
    return u / np.linalg.norm(u)


def movement_offsets(move: Move, side: str, t: np.ndarray, amp_scale: float = 1.0,
                     phase: float = 0.0) -> np.ndarray:
    """Offsets (T, 3) in metres of a movement at normalised times ``t`` (T,) in [0, 1].

    ``phase`` (in cycles) shifts cyclic movements (used for alternating two-handed signs).
    """
    d = gb.direction(move.dir, side)
    amp = move.amp * amp_scale
    w = 2.0 * np.pi * (move.n * t + phase)
    if move.kind == "hold":
        s = np.zeros_like(t)
    elif move.kind == "tap":
        s = 0.5 + 0.5 * np.cos(w)
    elif move.kind == "repeat":
        s = np.sin(0.5 * w) ** 2
    elif move.kind == "shake":
        s = np.sin(w)
    elif move.kind in ("away", "arc"):
        s = ease(t)
    elif move.kind == "toward":
        s = 1.0 - ease(t)
    elif move.kind == "circle":
        u = _perp(d)
        v = np.cross(d, u)
        w0 = 2.0 * np.pi * phase
        return amp * ((np.cos(w) - np.cos(w0))[:, None] * u + (np.sin(w) - np.sin(w0))[:, None] * v)
    else:
        raise ValueError(f"unknown movement {move.kind!r}")
    out = amp * s[:, None] * d
    if move.kind == "arc":
        out = out + move.height * amp_scale * np.sin(np.pi * t)[:, None] * np.array([0, 1.0, 0])
    return out


# --- one hand -----------------------------------------------------------------------------

@dataclass
class _HandTrack:
    side: str
    pose: np.ndarray     # (T, 45) flat hand pose
    rot: np.ndarray      # (T, 3, 3) world hand rotation
    wrist: np.ndarray    # (T, 3) world wrist position
    points: list         # per frame: name -> (3,) hand-frame points

    def world(self, name: str) -> np.ndarray:
        local = np.stack([p[name] for p in self.points])
        return self.wrist + np.einsum("tij,tj->ti", self.rot, local)


def _hand_track(hand: Hand, side: str, t: np.ndarray, rng: np.random.Generator,
                other: _HandTrack | None, phase: float = 0.0,
                skel: gb.Skeleton = gb.STANDARD) -> _HandTrack:
    T = len(t)
    te = ease(t)
    a0 = handshape_angles(hand.shape)
    a1 = handshape_angles(hand.end_shape or hand.shape)
    pose = angles_to_pose(a0[None] + (a1 - a0)[None] * te[:, None, None], side)
    points = [gb.hand_points(p, side) for p in pose]
    f = gb.direction(hand.fingers, side)
    r0 = gb.hand_rotation(f, gb.direction(hand.palm, side), side)
    twist = np.radians(hand.twist) * (1.0 if side == "right" else -1.0)
    rot = Rotation.from_rotvec((twist * te)[:, None] * f).as_matrix() @ r0
    sx = 1.0 if side == "left" else -1.0
    off = np.array([hand.offset[0] * sx, hand.offset[1], hand.offset[2]])
    off = off + rng.normal(0.0, 0.005, 3)
    if hand.loc.startswith("nondom:"):
        if other is None:
            raise ValueError(f"location {hand.loc!r} needs the other hand")
        base = other.world(hand.loc.split(":", 1)[1])
    else:
        base = np.broadcast_to(skel.side_point(hand.loc, side), (T, 3))
    target = base + off + movement_offsets(hand.move, side, t, rng.uniform(0.9, 1.1), phase)
    contact = np.stack([p[hand.contact] for p in points])
    wrist = target - np.einsum("tij,tj->ti", rot, contact)
    return _HandTrack(side, pose, rot, wrist, points)


# --- non-manual features --------------------------------------------------------------------

def _syllables(word: str) -> int:
    groups, prev = 0, False
    for ch in word.lower():
        v = ch in "aeiouy"
        groups += v and not prev
        prev = v
    return max(1, groups)


def _nonmanual(sign: Sign, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Head rotation (T,3), jaw pose (T,3) and expression (T,10) of a sign."""
    T = len(t)
    env = ease(np.minimum(1.0, np.minimum(t, 1.0 - t) / 0.2))
    head = np.zeros((T, 3))
    jaw = np.zeros((T, 3))
    expr = np.zeros((T, 10))
    for name in sign.nmf:
        if name == "nod":
            head[:, 0] += 0.15 * np.sin(4.0 * np.pi * t) * env
        elif name == "shake":
            head[:, 1] += 0.22 * np.sin(4.0 * np.pi * t) * env
        elif name == "question":
            head[:, 0] += 0.08 * env
            expr[:, EXPRESSION_INDEX["brow_furrow"]] += 1.0 * env
        elif name in ("yn_question", "brow_raise"):
            head[:, 0] -= 0.05 * env
            expr[:, EXPRESSION_INDEX["brow_raise"]] += 1.0 * env
        elif name == "smile":
            expr[:, EXPRESSION_INDEX["smile"]] += 0.8 * env
        elif name == "frown":
            expr[:, EXPRESSION_INDEX["frown"]] += 0.8 * env
            expr[:, EXPRESSION_INDEX["brow_furrow"]] += 0.4 * env
        elif name == "puff":
            expr[:, EXPRESSION_INDEX["cheek_puff"]] += 1.0 * env
        elif name == "mouth":
            jaw[:, 0] += 0.12 * np.abs(np.sin(4.0 * np.pi * t)) * env
        else:
            raise ValueError(f"{sign.gloss}: unknown non-manual feature {name!r}")
    if sign.kind == "sign":  # mouthing of the first English word: jaw opens per syllable
        k = _syllables(sign.words[0])
        mouth = np.maximum(0.0, np.sin(np.pi * k * np.clip((t - 0.15) / 0.7, 0.0, 1.0)))
        jaw[:, 0] += 0.07 * mouth
        expr[:, EXPRESSION_INDEX["jaw_open"]] += 0.5 * mouth
        expr[:, EXPRESSION_INDEX["lip_round"]] += 0.3 * mouth * ("o" in sign.words[0])
    return head, jaw, expr


# --- one gloss ----------------------------------------------------------------------------

def build_gloss(sign: Sign, seed: int = 0, fps: float = 25.0,
                skel: gb.Skeleton = gb.STANDARD) -> dict[str, np.ndarray]:
    """SMPL-X blocks (N, k) float32 of one gloss (see :data:`signsplat.motion.clips.BLOCK_SIZES`)."""
    rng = np.random.default_rng([seed, zlib.crc32(sign.gloss.encode())])
    scale = rng.uniform(0.93, 1.07)
    n = max(3, int(round(sign.duration * scale * fps)))
    t = np.linspace(0.0, 1.0, n)
    nd_side = "left" if DOMINANT == "right" else "right"
    if isinstance(sign.nondom, Hand):
        nd = _hand_track(sign.nondom, nd_side, t, rng, None, skel=skel)
        dom = _hand_track(sign.dom, DOMINANT, t, rng, nd, skel=skel)
    elif sign.nondom in ("mirror", "alternate"):
        dom = _hand_track(sign.dom, DOMINANT, t, rng, None, skel=skel)
        phase = 0.5 if sign.nondom == "alternate" else 0.0
        # directions and offsets are side-relative, so the same spec mirrors itself
        nd = _hand_track(sign.dom, nd_side, t, rng, None, phase, skel=skel)
    elif sign.nondom is None:
        dom = _hand_track(sign.dom, DOMINANT, t, rng, None, skel=skel)
        nd = _hand_track(REST, nd_side, t, rng, None, skel=skel)
    else:
        raise ValueError(f"{sign.gloss}: bad nondom {sign.nondom!r}")
    body = np.zeros((n, 63))
    for track in (dom, nd):
        swivel = gb.best_swivel(track.wrist, track.rot, track.side, skel)
        arm = gb.arm_ik(track.wrist, track.rot, track.side, skel, swivel=swivel)
        for joint, aa in zip(("shoulder", "elbow", "wrist"), arm):
            slot = gb.BODY_SLOT[f"{track.side}_{joint}"]
            body[:, slot:slot + 3] = aa
    head, jaw, expr = _nonmanual(sign, t)
    body[:, gb.BODY_SLOT["head"]:gb.BODY_SLOT["head"] + 3] = head
    hands = {dom.side: dom.pose, nd.side: nd.pose}
    return {
        "body_pose": body.astype(np.float32),
        "left_hand_pose": hands["left"].astype(np.float32),
        "right_hand_pose": hands["right"].astype(np.float32),
        "jaw_pose": jaw.astype(np.float32),
        "expression": expr.astype(np.float32),
    }


def all_signs() -> list[Sign]:
    """Every gloss of the library: the signs, then the 26 letters A..Z."""
    return list(SIGNS) + [letter_sign(c) for c in sorted(LETTERS)]


def _components(sign: Sign) -> str:
    def hand(h):
        return None if h is None or isinstance(h, str) else {
            "shape": h.shape, "end_shape": h.end_shape, "loc": h.loc, "palm": h.palm,
            "fingers": h.fingers, "contact": h.contact, "move": h.move.kind,
            "twist_deg": h.twist}
    return json.dumps({"dominant": DOMINANT, "dom": hand(sign.dom),
                       "nondom": sign.nondom if isinstance(sign.nondom, str) or sign.nondom is None
                       else hand(sign.nondom), "nmf": list(sign.nmf)})


def build_gloss_library(seed: int = 0, fps: float = 25.0) -> pd.DataFrame:
    """The whole library as a ``gloss_library`` table (one row per gloss, deterministic).

    Extra columns: ``components`` (JSON: handshapes, locations, movement, non-manual features).
    Results are cached per (seed, fps) in the process; every call returns fresh arrays.
    """
    if fps <= 0:
        raise ValueError(f"fps must be > 0, got {fps}")
    rows = _library_rows(int(seed), float(fps))
    return pd.DataFrame([{k: (v.copy() if isinstance(v, np.ndarray) else
                              list(v) if isinstance(v, list) else v) for k, v in r.items()}
                         for r in rows])


@lru_cache(maxsize=4)
def _library_rows(seed: int, fps: float) -> tuple[dict, ...]:
    rows = []
    for sign in all_signs():
        blocks = build_gloss(sign, seed, fps)
        n = blocks["body_pose"].shape[0]
        rows.append({
            "gloss": sign.gloss, "words": list(sign.words), "kind": sign.kind,
            "fps": float(fps), "num_frames": np.int32(n),
            "source": f"{SOURCE}, seed={seed}", "licence": LICENCE, "hand_mean": "flat",
            **{k: v.reshape(-1) for k, v in blocks.items()},
            "components": _components(sign),
        })
    return tuple(rows)


def write_gloss_library(path: str | os.PathLike, seed: int = 0, fps: float = 25.0) -> Path:
    """Build the library and write it atomically as Parquet (table ``gloss_library``)."""
    df = build_gloss_library(seed, fps)
    meta = {"hand_mean": "flat", "seed": str(seed), "fps": str(fps), "dominant": DOMINANT,
            "expression_index": json.dumps(EXPRESSION_INDEX)}
    return write_table(df, path, "gloss_library", metadata=meta)
