"""One signer in a crowded frame: which of the people the pose detector finds is the signer,
kept the same over time, and the person mask restricted to that person.

Rules (config ``perception.signer``, or a sheet row's ``signer`` column):

- ``largest``: the person with the largest body (side of the pose detector's full-body
  square: twice the distance from the mid-hip point to the size/rotation point);
- ``central``: the person whose mid-hip point is nearest the frame's centre (distance over the
  frame's diagonal);
- ``box`` (``x, y, w, h`` in pixels of the extracted frames): the person whose body square
  overlaps the box most (none when nobody overlaps it).

Over time: once chosen, a person stays chosen while a detection's head box overlaps the last
chosen head box by at least ``track_iou`` (heads of different people hardly overlap, whole
bodies often do). When the track is lost the frame has no signer, and the last head box is
looked for again, for up to ``patience`` frames; then the rule chooses again.

Who the signer is, by colour: where two people cross, the pose model's region can slide from
the signer onto the other person, and the box rule, asked again, takes whoever stands where
the signer stood. So the signer's colours above the hips (a hue-saturation-value histogram of
their segmentation, :func:`appearance`) are kept from frame to frame, blended in only where
no one else overlaps them; when another person's colours match them better than the chosen
person's by more than ``appearance_margin`` (Bhattacharyya distance, 0 same to 1 disjoint)
and within ``appearance_max``, that person is taken instead ('appearance').

Mask: the pose landmark model's person segmentation (sigmoid of its logits, in each person's
region) mapped back to the frame; the signer's, above 0.5 and grown by ``margin`` x the body
size, minus the pixels a nearby person claims with a higher probability, multiplies the matting
model's alpha, so other people and the background around them drop out.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from signsplat.perception.pretrained import mediapipe as mp
from signsplat.perception.pretrained.wholebody import BLAZEPOSE_NAMES

RULES = ("largest", "central", "box")


@dataclass(frozen=True)
class SignerRule:
    """How the signer is chosen (fields of config ``perception.signer``)."""

    rule: str
    box: tuple[float, float, float, float] | None
    track_iou: float
    margin: float
    patience: int
    appearance_margin: float | None  # None: no identity check by colour
    appearance_max: float
    others_min_score: float

    def __post_init__(self):
        if self.rule not in RULES:
            raise ValueError(f"signer rule {self.rule!r} unknown; known: {', '.join(RULES)}")
        if self.rule == "box" and self.box is None:
            raise ValueError("signer rule 'box' needs a box x, y, w, h")

    @classmethod
    def from_config(cls, signer: dict) -> SignerRule:
        box = signer.get("box")
        margin = signer["appearance_margin"]
        return cls(signer["rule"], tuple(float(v) for v in box) if box else None,
                   float(signer["track_iou"]), float(signer["margin"]),
                   int(signer["patience"]), None if margin is None else float(margin),
                   float(signer["appearance_max"]), float(signer["others_min_score"]))


def parse_signer(text: str) -> dict:
    """A sheet cell -> ``{"rule": ..., "box": ...}``: 'largest', 'central' or 'x,y,w,h'."""
    text = text.strip()
    if text in ("largest", "central"):
        return {"rule": text, "box": None}
    parts = text.split(",")
    try:
        box = [float(p) for p in parts]
    except ValueError:
        box = []
    if len(box) != 4 or box[2] <= 0 or box[3] <= 0:
        raise ValueError(f"signer {text!r}: expected 'largest', 'central' or a box 'x,y,w,h' "
                         "with w, h > 0 (pixels)")
    return {"rule": "box", "box": box}


def body_boxes(det: mp.Detections) -> np.ndarray:
    """(N, 4) xyxy axis-aligned full-body squares: centre at the mid-hip keypoint, side twice
    its distance to the full-body size point."""
    hip, scale = det.keypoints[:, 0], det.keypoints[:, 1]
    half = np.linalg.norm(scale - hip, axis=1)
    return np.concatenate([hip - half[:, None], hip + half[:, None]], axis=1)


class SignerSelector:
    """Chooses the signer among each frame's detections, frame after frame (:meth:`reset` at a
    new view or sequence)."""

    def __init__(self, rule: SignerRule):
        self.rule = rule
        self.last_head: np.ndarray | None = None
        self.missing = 0  # frames since the tracked signer was last seen

    def reset(self) -> None:
        self.last_head = None
        self.missing = 0

    def keep(self, head: np.ndarray) -> None:
        """The signer was found (by this selector or another tracker) with this head box."""
        self.last_head, self.missing = head, 0

    def choose(self, det: mp.Detections, frame_wh: tuple[int, int]) -> tuple[int | None, str]:
        """(index into ``det`` or None, how: 'tracked' or the rule's name)."""
        if self.last_head is not None:
            overlap = mp.iou(self.last_head, det.boxes) if len(det) else np.zeros(1)
            best = int(np.argmax(overlap))
            if overlap[best] >= self.rule.track_iou:
                self.keep(det.boxes[best])
                return best, "tracked"
            self.missing += 1
            if self.missing <= self.rule.patience:
                return None, ""
            self.last_head = None
        if not len(det):
            return None, ""
        bodies = body_boxes(det)
        if self.rule.rule == "largest":
            i = int(np.argmax(bodies[:, 2] - bodies[:, 0]))
        elif self.rule.rule == "central":
            w, h = frame_wh
            d = np.linalg.norm(det.keypoints[:, 0] - [w / 2, h / 2], axis=1)
            i = int(np.argmin(d))
        else:
            x, y, bw, bh = self.rule.box
            overlap = mp.iou(np.array([x, y, x + bw, y + bh]), bodies)
            i = int(np.argmax(overlap))
            if overlap[i] <= 0:
                return None, ""
        self.keep(det.boxes[i])
        return i, self.rule.rule


def person_probability(seg_logits: np.ndarray, roi: mp.Roi,
                       frame_hw: tuple[int, int]) -> np.ndarray:
    """Float32 (H, W) probability that a frame pixel belongs to the person: the pose model's
    segmentation logits (h, w, in its crop ``roi``) through a sigmoid, mapped to the frame
    (0 outside the crop)."""
    h, w = seg_logits.shape
    prob = (1.0 / (1.0 + np.exp(-np.clip(seg_logits, -60, 60)))).astype(np.float32)
    H, W = frame_hw
    # warpAffine with WARP_INVERSE_MAP takes frame pixel -> crop pixel: the crop's inverse
    inv = cv2.invertAffineTransform(mp.crop_matrix(roi, (w, h)))
    return cv2.warpAffine(prob, inv, (W, H), flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
                          borderMode=cv2.BORDER_CONSTANT, borderValue=0)


def _bones(pairs) -> tuple[tuple[int, int], ...]:
    return tuple((BLAZEPOSE_NAMES.index(a), BLAZEPOSE_NAMES.index(b)) for a, b in pairs)


#: BlazePose's head and torso bones, drawn whatever their points' visibility (a torso is
#: there even where the frame cuts off the hips)
CORE_BONES = _bones((
    ("left_ear", "right_ear"), ("nose", "left_ear"), ("nose", "right_ear"),
    ("nose", "left_shoulder"), ("nose", "right_shoulder"), ("left_shoulder", "right_shoulder"),
    ("left_shoulder", "left_hip"), ("right_shoulder", "right_hip"), ("left_hip", "right_hip"),
    ("left_shoulder", "right_hip"), ("right_shoulder", "left_hip")))
#: BlazePose's limb bones, drawn where both their points are visible (an arm hidden behind
#: someone else must not claim them)
LIMB_BONES = _bones((f"{side}_{a}", f"{side}_{b}") for side in ("left", "right") for a, b in (
    ("shoulder", "elbow"), ("elbow", "wrist"), ("wrist", "index"), ("wrist", "pinky"),
    ("wrist", "thumb"), ("index", "pinky"), ("hip", "knee"), ("knee", "ankle"),
    ("ankle", "heel"), ("heel", "foot_index"), ("ankle", "foot_index")))
#: a limb bone is drawn when both its points' visibility is at least this
BONE_VISIBILITY = 0.5


def skeleton_distance(points: np.ndarray, visibility: np.ndarray,
                      frame_hw: tuple[int, int], limbs: bool = True) -> np.ndarray:
    """Float32 (H, W) distance in pixels to a pose's nearest bone (:data:`CORE_BONES`, and
    unless not ``limbs`` :data:`LIMB_BONES` with visible ends) from its landmarks (>= 33, 2)
    in frame pixels and their visibility; infinite everywhere when no bone has finite ends."""
    canvas = np.full(frame_hw, 255, np.uint8)
    drawn = 0
    bones = list(CORE_BONES) + [(a, b) for a, b in LIMB_BONES if limbs and
                                min(visibility[a], visibility[b]) >= BONE_VISIBILITY]
    for a, b in bones:
        ends = points[[a, b]]
        if np.isfinite(ends).all():
            pa, pb = np.clip(np.round(ends), -1e4, 1e4).astype(int)
            cv2.line(canvas, tuple(map(int, pa)), tuple(map(int, pb)), 0, 1)
            drawn += 1
    if not drawn or canvas.all():  # no bone, or every bone outside the frame
        return np.full(frame_hw, np.inf, np.float32)
    return cv2.distanceTransform(canvas, cv2.DIST_L2, 3)


#: BlazePose's nose and ears: where a person's head is
HEAD = tuple(BLAZEPOSE_NAMES.index(n) for n in ("nose", "left_ear", "right_ear"))
#: another pose with its head within this share of the signer's shoulder width of the
#: signer's head and torso bones has taken the signer for part of itself (a neighbour's
#: shoulder may touch the signer's; their head does not)
CONFUSED_REACH = 0.3


SHOULDERS = (BLAZEPOSE_NAMES.index("left_shoulder"), BLAZEPOSE_NAMES.index("right_shoulder"))


def shoulder_width(points: np.ndarray) -> float:
    """Pixels between a pose's shoulders (0 when either is not finite)."""
    d = float(np.linalg.norm(points[SHOULDERS[0]] - points[SHOULDERS[1]]))
    return d if np.isfinite(d) else 0.0


def confused_pose(points: np.ndarray, signer_core: np.ndarray, reach: float) -> bool:
    """Whether a pose's head (nose or an ear; landmarks >= 33, 2 in frame pixels) lies within
    ``reach`` pixels of the signer's head and torso bones (``signer_core``: their
    :func:`skeleton_distance` without limbs): a pose unsure where one person ends and the
    other begins, whose bones would cut into the signer."""
    h, w = signer_core.shape
    for x, y in points[list(HEAD)]:
        if np.isfinite(x) and np.isfinite(y) and 0 <= x < w and 0 <= y < h \
                and signer_core[int(y), int(x)] < reach:
            return True
    return False


def person_mask(chosen: np.ndarray, others: list[np.ndarray], body_size: float,
                margin: float, chosen_bones: np.ndarray | None = None,
                others_bones: list[np.ndarray | None] | None = None) -> np.ndarray:
    """Bool (H, W) region of the chosen person from per-person probabilities (H, W): where
    the chosen person's is above 0.5, grown by ``margin * body_size`` pixels, minus what
    another person claims.

    Without skeletons (or without the other's: None), another person claims the pixels where
    their probability is above 0.5 and the chosen person's. With them (``*_bones``:
    :func:`skeleton_distance` maps), they claim where theirs is above 0.5 and either the
    chosen person's is not or their skeleton is the nearer one; that claim, grown by the same
    margin, also takes the pixels around it that lie nearer their skeleton (the outline the
    chosen person's segmentation still covers). The pose model segments everyone in its
    crop, so two people side by side often both claim each other with certainty."""
    region = (chosen > 0.5).astype(np.uint8)
    grow = int(round(margin * body_size))
    disk = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * grow + 1, 2 * grow + 1))
    if grow > 0:
        region = cv2.dilate(region, disk)
    keep = region.astype(bool)
    for i, other in enumerate(others):
        if chosen_bones is None or others_bones is None or others_bones[i] is None:
            keep &= ~((other > 0.5) & (other > chosen))
            continue
        theirs = others_bones[i] < chosen_bones
        claim = (other > 0.5) & ((chosen <= 0.5) | theirs)
        if grow > 0:
            claim |= cv2.dilate(claim.astype(np.uint8), disk).astype(bool) & theirs
        keep &= ~claim
    return keep


#: hue x saturation x value bins of :func:`appearance` (OpenCV's hue runs 0-180)
APPEARANCE_BINS = (12, 4, 4)
#: fewer pixels than this above the hips: no appearance (a person at the frame's edge)
APPEARANCE_MIN_PIXELS = 50
#: weight of a frame's colours in the signer's kept ones (a running blend)
APPEARANCE_RATE = 0.1
#: largest share of the signer's pixels that others may claim for their colours to be blended
APPEARANCE_OVERLAP = 0.05


def appearance(hsv: np.ndarray, region: np.ndarray, hip_y: float) -> np.ndarray | None:
    """A person's colours: the float32 histogram (:data:`APPEARANCE_BINS`, summing to 1) of
    a frame's hue, saturation and value (``hsv``: OpenCV's RGB2HSV of the frame, converted
    once for everyone in it) over the bool ``region`` above the row
    ``hip_y`` (the clothes and head, not the legs, which others' often resemble); None when
    fewer than :data:`APPEARANCE_MIN_PIXELS` pixels are there, or no hip row is known."""
    if not np.isfinite(hip_y):
        return None
    top = region.copy()
    top[max(int(np.ceil(hip_y)), 0):] = False
    if int(top.sum()) < APPEARANCE_MIN_PIXELS:
        return None
    hist = cv2.calcHist([hsv], [0, 1, 2], top.astype(np.uint8), list(APPEARANCE_BINS),
                        [0, 180, 0, 256, 0, 256])
    return (hist / hist.sum()).astype(np.float32)


def appearance_distance(a: np.ndarray, b: np.ndarray) -> float:
    """Bhattacharyya distance of two :func:`appearance` histograms: 0 same, 1 disjoint."""
    return float(cv2.compareHist(a, b, cv2.HISTCMP_BHATTACHARYYA))


def appearance_switch(signer: float, others: list[float], margin: float,
                      max_distance: float) -> int | None:
    """Index into ``others`` of the person to take instead of the chosen one, given each
    one's appearance distance to the signer's kept colours (NaN: not measured), or None: the
    best-matching other, if it matches better than the chosen person by more than ``margin``
    and is within ``max_distance`` itself. A chosen person whose colours were not measured
    (too little of them above the hips) is kept: nothing speaks against them."""
    d = np.asarray(others, dtype=np.float64)
    if np.isnan(signer) or not d.size or np.isnan(d).all():
        return None
    best = int(np.nanargmin(d))
    return best if d[best] + margin < signer and d[best] <= max_distance else None


#: two mid-hip points closer than this share of the signer's body size are one person's
#: (people standing shoulder to shoulder are about a quarter apart)
SAME_PERSON = 0.125

# Columns of a persons row (the ``persons`` table adds scene, view, frame).
PERSON_COLUMNS = ("person", "score", "hip_x", "hip_y", "scale_x", "scale_y", "head_x0",
                  "head_y0", "head_x1", "head_y1", "appearance", "chosen", "chosen_by")


def _detection_row(row: int, det: mp.Detections, j: int) -> dict:
    """The persons row numbered ``row`` of detection ``j`` (no appearance, not chosen)."""
    return dict(zip(PERSON_COLUMNS, (
        row, float(det.scores[j]), *det.keypoints[j, 0], *det.keypoints[j, 1], *det.boxes[j],
        np.nan, False, ""), strict=True))


class SignerMasking:
    """The segment stage's signer step with the pretrained detectors: per frame, the people
    the pose detector finds, the signer among them and the matting alpha restricted to the
    signer (:func:`person_mask`).

    The signer is followed as MediaPipe's pose tracking follows a person: the pose model runs
    in the region its landmarks gave in the last frame (auxiliary points 33, 34); while it
    still finds a pose there, that is the signer ('tracked'; the detection whose mid-hip point
    is within a quarter body of it, if any, is marked). Otherwise :class:`SignerSelector`
    chooses among the detections (head-box tracking, then the rule). Either choice is then
    checked against the signer's kept colours (:func:`appearance_switch`)."""

    max_people = 4  # the signer's neighbours whose regions are cut out of the signer's

    def __init__(self, spec, rule: SignerRule, threads: int = 1):
        from signsplat.perception.pretrained.keypointer import MediaPipeWholeBody

        self.model = MediaPipeWholeBody(spec, threads)
        self.selector = SignerSelector(rule)
        self.rule = rule
        self._view = None
        self.prev: tuple[np.ndarray, np.ndarray] | None = None  # last (hip, scale point)
        self.colours: np.ndarray | None = None  # the signer's kept appearance

    def __call__(self, image: np.ndarray, alpha: np.ndarray,
                 view: int) -> tuple[np.ndarray, list[dict]]:
        """(restricted alpha, one row per detected person) for one frame."""
        if view != self._view:
            self.selector.reset()
            self.prev, self.colours = None, None
            self._view = view
        h, w = image.shape[:2]
        min_presence = self.model.spec.min_pose_presence
        strong = self.model.spec.min_detection_score
        det, weak = self.model.detect_persons_at(
            image, (strong, min(strong, self.rule.others_min_score)))
        rows = [_detection_row(j, det, j) for j in range(len(det))]
        chosen, how, signer = None, "", None
        if self.prev is not None:
            pose = self.model.pose(image, self.model.person_roi(*self.prev))
            if pose.presence >= min_presence:
                hip, scale = pose.points[33], pose.points[34]
                body = 2.0 * float(np.linalg.norm(scale - hip))
                near = np.linalg.norm(det.keypoints[:, 0] - hip, axis=1) if len(det) else []
                if len(det) and near.min() < body / 4:
                    chosen = int(np.argmin(near))
                    self.selector.keep(det.boxes[chosen])
                else:  # the pose model still sees the signer; the detector missed them
                    chosen = len(rows)
                    rows.append(dict(zip(PERSON_COLUMNS, (
                        chosen, np.nan, *hip, *scale, *[np.nan] * 5, False, ""), strict=True)))
                how, signer = "tracked", (pose, hip, scale)
        if signer is None:
            chosen, how = self.selector.choose(det, (w, h))
            if chosen is not None:
                hip, scale = det.keypoints[chosen, 0], det.keypoints[chosen, 1]
                pose = self.model.pose(image, self.model.person_roi(hip, scale))
                if pose.presence >= min_presence:
                    signer = (pose, hip, scale)
        if signer is None:
            self.prev = None
            return np.zeros_like(alpha), rows
        pose, hip, scale = signer
        prob = person_probability(pose.segmentation, pose.roi, (h, w))
        colour_check = self.rule.appearance_margin is not None
        others = []  # (row, pose, probability) of the people around the signer
        unsure = []  # detected people whose pose model is unsure: colour candidates only
        for j in range(min(len(det), self.max_people)):
            if j == chosen:
                continue
            other = self.model.pose(image, self.model.person_roi(*det.keypoints[j, :2]))
            sure_pose = other.presence >= min_presence
            if sure_pose or colour_check:
                person = (j, other, person_probability(other.segmentation, other.roi, (h, w)))
                (others if sure_pose else unsure).append(person)
        sure = len(others)
        candidates = others + unsure  # the ones the colour check may take instead
        others += self._weak_neighbours(image, rows, det, weak, pose, len(others))
        if colour_check:
            k = self._check_identity(image, rows, chosen, prob, pose, candidates, others[sure:])
            if k is not None:  # another person wears the signer's colours: take them
                j, new_pose, new_prob = candidates[k]
                if k < sure:
                    others[k] = (chosen, pose, prob)
                else:  # the one taken for the signer now stands beside them
                    others.append((chosen, pose, prob))
                chosen, pose, prob, how = j, new_pose, new_prob, "appearance"
                hip, scale = det.keypoints[j, 0], det.keypoints[j, 1]
                self.selector.keep(det.boxes[j])
        rows[chosen]["chosen"], rows[chosen]["chosen_by"] = True, how
        self.prev = (pose.points[33], pose.points[34])
        body = 2.0 * float(np.linalg.norm(scale - hip))
        bones = others_bones = None
        if others:  # the skeletons decide only between people
            core = skeleton_distance(pose.points, pose.visibility, (h, w), limbs=False)
            reach = CONFUSED_REACH * shoulder_width(pose.points)
            bones = skeleton_distance(pose.points, pose.visibility, (h, w))
            others_bones = [None if confused_pose(o[1].points, core, reach) else
                            skeleton_distance(o[1].points, o[1].visibility, (h, w))
                            for o in others]
        region = person_mask(prob, [o[2] for o in others], body, self.rule.margin, bones,
                             others_bones)
        return alpha * region, rows

    def _weak_neighbours(self, image, rows, det, weak, pose, have: int) -> list:
        """(row, pose, probability) of the people the detector scored between
        ``others_min_score`` and ``min_detection_score`` (neighbours close to the signer often
        score so), for cutting them out of the signer's region; a row is added for each.
        A detection within :data:`SAME_PERSON` of the signer's body from someone already known,
        or whose pose is, is that person."""
        min_presence = self.model.spec.min_pose_presence
        hip, scale = pose.points[33], pose.points[34]
        same = SAME_PERSON * 2.0 * float(np.linalg.norm(scale - hip))
        known = [hip, *det.keypoints[:, 0]]  # the signer's and the detected people's hips
        out = []

        def known_near(point) -> bool:
            return np.linalg.norm(np.asarray(known) - point, axis=1).min() < same

        for j in range(len(weak)):
            if have + len(out) >= self.max_people:
                break
            if known_near(weak.keypoints[j, 0]):
                continue
            other = self.model.pose(image, self.model.person_roi(*weak.keypoints[j, :2]))
            if other.presence < min_presence or known_near(other.points[33]):
                continue
            known.append(other.points[33])
            row = len(rows)
            rows.append(_detection_row(row, weak, j))
            out.append((row, other, person_probability(other.segmentation, other.roi,
                                                       image.shape[:2])))
        return out

    def _check_identity(self, image, rows, chosen, prob, pose, others,
                        bystanders=()) -> int | None:
        """Index into ``others`` of the person to take instead of the chosen one, or None,
        from everyone's colours against the signer's kept ones (written to the rows' column
        ``appearance``; ``bystanders`` are measured too but never taken). The signer's colours
        of this frame are blended into the kept ones where nobody else claims more than
        :data:`APPEARANCE_OVERLAP` of their region."""
        hsv = cv2.cvtColor(image, cv2.COLOR_RGB2HSV)

        def colours(pr, ps):
            return appearance(hsv, pr > 0.5, float(ps.points[33, 1]))

        people = [(chosen, pose, prob), *others, *bystanders]
        seen = [colours(pr, ps) for _, ps, pr in people]
        k = None
        if self.colours is not None:
            dist = [np.nan if c is None else appearance_distance(self.colours, c) for c in seen]
            for (row, _, _), d in zip(people, dist):
                rows[row]["appearance"] = d
            k = appearance_switch(dist[0], dist[1:1 + len(others)], self.rule.appearance_margin,
                                  self.rule.appearance_max)
        signer = 0 if k is None else k + 1
        if seen[signer] is not None:
            region = people[signer][2] > 0.5
            claimed = np.zeros_like(region)
            for i, (_, _, pr) in enumerate(people):
                if i != signer:
                    claimed |= (pr > 0.5) & region
            if claimed.sum() <= APPEARANCE_OVERLAP * region.sum():
                mine = seen[signer]
                self.colours = mine if self.colours is None else \
                    (1 - APPEARANCE_RATE) * self.colours + APPEARANCE_RATE * mine
        return k
