"""The shipped keypoint model's body and face with MediaPipe's fingers (``perception.keypoints.
hands: mediapipe``).

The hand landmarker of the pretrained keypointer (:mod:`signsplat.perception.pretrained`) runs
on the same frames as the keypoint model. Per frame and side (of the configured
``hand_sides``), :func:`take_hands` puts its finger points in place of the model's when

- that hand was found (its points' mean score is at least ``min_score``), and
- its wrist lies within ``reach`` times the person's size (the longer side of the mask's box)
  of the model's wrist of the same side, whose score is at least ``min_score``: the two then
  agree on which hand is which, and on where the arm ends.

Where the landmarker looks (``hand_crop``): with ``model`` (the default), in the crop MediaPipe's
hand tracking takes around a hand's last 21 points, here the keypoint model's own points of
that hand in the same frame (:func:`hands_in_model_crops`; the hand model alone); with
``pose``, where MediaPipe's pose model puts the hand (the pretrained keypointer's own chain).

The hand's root point (the wrist) stays the model's: it is the end of the arm the model
detects with the body. So do the scores, which the fit uses as weights
(``fit.confidence_power``): the landmarker's scores would weigh the hands more than the fit's
balance of body and hands was set for. Why and what it gains: ``docs/avatar.md``, "MediaPipe's
fingers on the shipped body".
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from signsplat.body.joints import KP_LEFT_HAND, KP_RIGHT_HAND, NUM_KEYPOINTS

# COCO-WholeBody: per side the body's wrist and the hand's 21 points (root first)
SIDES = {"left": (9, KP_LEFT_HAND), "right": (10, KP_RIGHT_HAND)}
HAND_CROPS = ("model", "pose")
#: a hand whose points span fewer pixels (its crop's longer side, before MediaPipe's 2x) gives
#: the landmarker nothing to see, and a crop of no size cannot be made
MIN_HAND_PX = 4.0


def take_hands(xy: np.ndarray, sc: np.ndarray, hand_xy: np.ndarray, hand_sc: np.ndarray,
               boxes: list, min_score: float, reach: float, sides: tuple[str, ...]
               ) -> tuple[np.ndarray, np.ndarray, dict[str, int]]:
    """The keypoints ``xy`` (N, 133, 2) with the finger points of ``hand_xy`` (the hand
    landmarker's, same shape) where the module's rules take them; ``sc`` (N, 133) are the
    model's scores, ``hand_sc`` the landmarker's (they decide which hands are found, and the
    scores stay the model's); ``boxes`` are the frames' person boxes (x0, y0, x1, y1) or None
    (no person: nothing is taken); ``sides`` the sides whose fingers may be taken (the others
    stay the model's). Returns new arrays and per side of ``sides`` the number of frames
    taken."""
    unknown = sorted(set(sides) - set(SIDES))
    if unknown:
        raise ValueError(f"unknown hand side(s) {unknown}; known: {sorted(SIDES)}")
    xy, sc = np.array(xy, np.float32), np.array(sc, np.float32)
    hand_xy, hand_sc = np.asarray(hand_xy, np.float32), np.asarray(hand_sc, np.float32)
    n = len(xy)
    size = np.array([np.nan if b is None else max(b[2] - b[0], b[3] - b[1]) for b in boxes],
                    np.float64).reshape(n)
    taken = {}
    for side in sides:
        wrist, hand = SIDES[side]
        root, fingers = hand[0], list(hand[1:])
        found = np.nan_to_num(hand_sc[:, list(hand)].mean(axis=1), nan=0.0) >= min_score
        gap = np.linalg.norm(hand_xy[:, root] - xy[:, wrist], axis=-1)
        near = np.nan_to_num(gap, nan=np.inf) <= reach * np.nan_to_num(size, nan=0.0)
        ok = found & near & (np.nan_to_num(sc[:, wrist], nan=0.0) >= min_score)
        ok &= np.isfinite(hand_xy[:, fingers]).all(axis=(1, 2))
        xy[np.ix_(ok, fingers)] = hand_xy[np.ix_(ok, fingers)]
        taken[side] = int(ok.sum())
    return xy, sc, taken


def hands_in_model_crops(landmarker, images: list, xy: np.ndarray, sc: np.ndarray,
                         sides: tuple[str, ...], min_score: float, min_presence: float
                         ) -> tuple[np.ndarray, np.ndarray]:
    """The hand landmarker's points per frame and side of ``sides`` in the crop around the
    keypoint model's own 21 points of that hand (``xy`` (N, 133, 2), scores ``sc`` (N, 133)):
    MediaPipe's tracking crop (``landmarker.tracked_hand``), run where those points are
    finite, span at least :data:`MIN_HAND_PX` and score ``min_score`` on average. Returns
    (N, 133, 2) points (NaN where no hand was found) and (N, 133) scores (the hand's presence
    on its 21 points where it is at least ``min_presence``, else 0), as :func:`take_hands`
    reads the landmarker's."""
    n = len(images)
    hand_xy = np.full((n, NUM_KEYPOINTS, 2), np.nan, np.float32)
    hand_sc = np.zeros((n, NUM_KEYPOINTS), np.float32)
    for side in sides:
        hand = list(SIDES[side][1])
        for i, image in enumerate(images):
            pts = np.asarray(xy[i, hand], np.float64)
            if not np.isfinite(pts).all() or not np.nanmean(sc[i, hand]) >= min_score:
                continue
            if float(np.ptp(pts, axis=0).max()) < MIN_HAND_PX:
                continue
            found, _ = landmarker.tracked_hand(image, pts)
            if found.presence >= min_presence and np.isfinite(found.points).all():
                hand_xy[i, hand] = found.points
                hand_sc[i, hand] = found.presence
    return hand_xy, hand_sc


@dataclass(frozen=True)
class HandsSpec:
    """A keypoint model (``base``, a :class:`~signsplat.perception.contracts.KeypointSpec`)
    whose hands come from MediaPipe's hand landmarker (``hands``, a
    :class:`~signsplat.perception.pretrained.keypointer.MediaPipeSpec`)."""

    base: object
    hands: object
    min_score: float
    reach: float
    sides: tuple[str, ...]
    #: one of :data:`HAND_CROPS`: where the landmarker looks for a hand
    crop: str

    @property
    def device(self) -> str:
        return self.base.device


class HandsKeypointer:
    """Two keypointers on the same frames, their results merged by :func:`take_hands`: the
    keypoint model ``base`` and MediaPipe's hand landmarker, opened here for ``spec.crop``
    (the hand model alone for ``model``, the pretrained keypointer's chain for ``pose``)."""

    source = "onnx+mediapipe"
    num_keypoints = NUM_KEYPOINTS

    def __init__(self, base, spec: HandsSpec, threads: int = 1):
        from signsplat.perception.pretrained.graphs import HAND_LMK
        from signsplat.perception.pretrained.keypointer import (
            MediaPipeKeypointer,
            MediaPipeWholeBody,
        )

        if spec.crop not in HAND_CROPS:
            raise ValueError(f"unknown hand crop {spec.crop!r}; known: {list(HAND_CROPS)}")
        self.base, self.spec = base, spec
        self.hands = (MediaPipeWholeBody(spec.hands, threads, models=(HAND_LMK,))
                      if spec.crop == "model" else MediaPipeKeypointer(spec.hands, threads))
        self.batch_size, self.min_area = base.batch_size, base.min_area
        self.path = f"{base.path} + {spec.hands.cache}"
        self.taken = {side: 0 for side in spec.sides}
        self.frames = 0

    def detect(self, images: list, boxes: list, views: list[int], persons=None):
        """The base's keypoints with the hand landmarker's hands (:func:`take_hands`)."""
        xy, sc = self.base.detect(images, boxes, views, persons)
        if self.spec.crop == "model":
            hand_xy, hand_sc = hands_in_model_crops(
                self.hands, images, xy, sc, self.spec.sides, self.spec.min_score,
                self.spec.hands.min_hand_presence)
        else:
            hand_xy, hand_sc = self.hands.detect(images, boxes, views, persons)
        xy, sc, taken = take_hands(xy, sc, hand_xy, hand_sc, boxes, self.spec.min_score,
                                   self.spec.reach, self.spec.sides)
        for side, k in taken.items():
            self.taken[side] += k
        self.frames += len(images)
        return xy, sc

    def summary(self) -> str:
        """How many frames took the landmarker's hands, for the stage's log."""
        return (f"MediaPipe's hands (crop: {self.spec.crop}) taken in " + ", ".join(
            f"{n} of {self.frames} frames ({side})" for side, n in self.taken.items()))

    def finish(self, frames, xy, sc):
        """One view's keypoints after its last frame: the base's own finishing."""
        return self.base.finish(frames, xy, sc)
