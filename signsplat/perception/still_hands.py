"""A neighbour's hand taken for the signer's, told apart by motion over a clip.

A keypointer that looks for a hand near the pose's wrist (the pose's hand region, tracking,
palm search) finds whatever hand lies there. When the signer's own hand is hidden behind a
person in front of him, that is the other person's hand, and on a single frame nothing tells
the two apart. Over frames something does: the found hand stays put while the signer's wrist
(the pose's, which follows his arm) moves.

Per view and side, the frames with a found hand are cut into tracks (runs of frames at most
``max_gap`` apart whose hand wrist moves at most ``max_step`` palm lengths between found
frames). A track of at least ``min_frames`` frames is dropped when the median step of its
hand's wrist, times ``ratio``, is below the median step of the pose's wrist over the same
frame pairs, and the pose's wrist moves at least ``min_motion`` palm lengths per step (a
still pose cannot tell). Only pairs where the pose's wrist scores ``trust`` or more count.
The palm length (wrist to middle knuckle) is the median of the view's found hands, so the
rule does not depend on image size.
"""

from __future__ import annotations

import numpy as np

from signsplat.perception.quality import PARTS, WRIST_ELBOW, hand_found

HANDS = {side: PARTS[f"{side}_hand"] for side in ("left", "right")}
WRIST = {side: WRIST_ELBOW[f"{side}_hand"][0] for side in HANDS}
MIDDLE_KNUCKLE = 9  # of the 21 hand points (wrist 0, then 4 per finger from the thumb)


def hand_tracks(frames: np.ndarray, wrist: np.ndarray, max_gap: int,
                max_step: float) -> list[np.ndarray]:
    """Indices of ``frames`` (sorted, (T,)) cut into tracks: consecutive entries at most
    ``max_gap`` frames apart whose ``wrist`` (T, 2) moves at most ``max_step`` pixels."""
    if len(frames) == 0:
        return []
    step = np.linalg.norm(np.diff(wrist, axis=0), axis=1)
    cut = (np.diff(frames) > max_gap) | ~(step <= max_step)
    return np.split(np.arange(len(frames)), np.flatnonzero(cut) + 1)


def still_hand_frames(frames: np.ndarray, xy: np.ndarray, sc: np.ndarray, side: str, *,
                      ratio: float, min_score: float = 0.5, min_frames: int = 4,
                      max_gap: int = 2, max_step: float = 4.0, min_motion: float = 0.25,
                      trust: float = 0.5) -> np.ndarray:
    """(T,) bool: frames whose ``side`` hand belongs to a still track (module docstring).

    ``frames`` (T,) sorted frame numbers of one view, ``xy`` (T, 133, 2), ``sc`` (T, 133);
    a hand is found where at least half of its points score ``min_score``."""
    ids = list(HANDS[side])
    found = hand_found(sc, f"{side}_hand", min_score)
    out = np.zeros(len(frames), bool)
    idx = np.flatnonzero(found & np.isfinite(xy[:, ids[0]]).all(1))
    if ratio <= 0 or len(idx) < min_frames:
        return out
    hand = xy[idx, ids[0]].astype(np.float64)
    palm = float(np.nanmedian(np.linalg.norm(xy[idx, ids[MIDDLE_KNUCKLE]] - hand, axis=1)))
    if not np.isfinite(palm) or palm <= 0:
        return out
    pose = xy[idx, WRIST[side]].astype(np.float64)
    sure = sc[idx, WRIST[side]] >= trust
    for t in hand_tracks(np.asarray(frames)[idx], hand, max_gap, max_step * palm):
        if len(t) < min_frames:
            continue
        pairs = sure[t[:-1]] & sure[t[1:]]
        if pairs.sum() < min_frames - 1:
            continue
        dh = np.linalg.norm(np.diff(hand[t], axis=0), axis=1)[pairs]
        dp = np.linalg.norm(np.diff(pose[t], axis=0), axis=1)[pairs]
        moved = float(np.median(dp))
        if float(np.median(dh)) * ratio < moved and moved >= min_motion * palm:
            out[idx[t]] = True
    return out


def drop_still_hands(frames: np.ndarray, xy: np.ndarray, sc: np.ndarray, **rule
                     ) -> tuple[np.ndarray, np.ndarray, dict[str, int]]:
    """Copies of one view's ``xy`` / ``sc`` with the hands of still tracks cleared (NaN, score
    0), and per side the number of frames cleared; ``rule``: :func:`still_hand_frames`'s
    keywords."""
    xy, sc = xy.copy(), sc.copy()
    dropped = {}
    for side, ids in HANDS.items():
        bad = still_hand_frames(frames, xy, sc, side, **rule)
        xy[np.ix_(bad, list(ids))] = np.nan
        sc[np.ix_(bad, list(ids))] = 0.0
        dropped[side] = int(bad.sum())
    return xy, sc, dropped
