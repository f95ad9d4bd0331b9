"""A whole-body keypointer from MediaPipe's models (converted to ONNX), as MediaPipe Holistic
chains them, mapped to COCO-WholeBody 133.

Per frame (ROI = rotated square region of interest, :mod:`.mediapipe`):

1. **Person**: the pose detector on the whole frame (letterboxed to 224 x 224) gives people
   with a mid-hip point and a point encoding body size and rotation; the person's ROI is
   centred on the hip point, side twice their distance, turned so the body is upright, then
   grown 1.25x. With ``track`` the next frame reuses the ROI of this frame's landmarks
   (auxiliary points 33, 34) instead of detecting again, as MediaPipe's pose tracking does.
2. **Pose**: 39 landmarks in that ROI (256 x 256), refined with their heatmaps (7 x 7
   windows); visibility and presence are sigmoid probabilities; the pose counts when its
   presence flag is at least ``min_pose_presence``.
3. **Hands** (each side whose wrist visibility is at least ``min_wrist_visibility``): a loose
   ROI from the pose's wrist, index and pinky points (centre at the estimated middle finger,
   2.7x, shifted 0.1 towards the fingers) is re-cropped by MediaPipe's hand re-crop model
   (2 points -> a tight ROI), in which the hand landmark model (224 x 224) gives 21 points,
   their presence and the handedness. With ``track``, a hand not found there is looked for
   again in the ROI of the last frame's hand landmarks (2x, shifted 0.1 towards the fingers,
   as MediaPipe's hand tracking does) and kept when :func:`tracked_hand_kept` says so: its
   wrist near the pose's, which keeps a neighbour's hand in front of a hidden one out.
   When both miss, the palm detector (192 x 192) looks in a square around the pose's wrist
   (``palm_search`` times the person's region); each palm gives a hand ROI (its box, turned
   from the palm's wrist point to its middle knuckle, 2.6x, shifted half a palm towards the
   fingers, as MediaPipe's hand pipeline does), and the hand found there whose wrist lies
   nearest the pose's wrist is taken.
4. **Face**: an ROI from the pose's face points (their box, turned eye-to-eye, 3x) in which
   the short-range face detector (128 x 128) finds faces; the one whose nose tip is nearest
   the pose's nose (not MediaPipe's best-scored one: in a crowd that can be a neighbour's)
   gives the face ROI from its eye keypoints (2x, shifted 0.1 up), in which the face mesh
   model (192 x 192) gives 468 points and a presence logit.

Hands are assigned by the pose's sides; the hand model's handedness is kept as a check
(:func:`~.wholebody.left_hand_prob`: MediaPipe's label assumes mirrored images).

After a view's last frame, :meth:`MediaPipeKeypointer.finish` clears the hands that stay put
while the pose's wrist moves (``still_hand_ratio``, :mod:`signsplat.perception.still_hands`):
a neighbour's hand in front of the signer's hidden one.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from signsplat.body.joints import NUM_KEYPOINTS
from signsplat.perception.contracts import ModelContractError, open_session
from signsplat.perception.pretrained import mediapipe as mp
from signsplat.perception.pretrained.fetch import FetchError, model_file
from signsplat.perception.pretrained.graphs import (
    FACE_DET,
    FACE_LMK,
    HAND_LMK,
    HAND_RECROP,
    MODELS,
    PALM_DET,
    POSE_DET,
    POSE_LMK,
)
from signsplat.perception.still_hands import drop_still_hands
from signsplat.perception.pretrained.wholebody import (
    BLAZEPOSE_NAMES,
    POSE_ELBOW,
    POSE_FACE_POINTS,
    POSE_HAND_POINTS,
    POSE_LEFT_EYE,
    POSE_RIGHT_EYE,
    HandResult,
    WholeBodyResult,
    left_hand_prob,
    to_coco_wholebody,
)

NMS_IOU = 0.3
POSE_HIPS = (BLAZEPOSE_NAMES.index("left_hip"), BLAZEPOSE_NAMES.index("right_hip"))


@dataclass(frozen=True)
class MediaPipeSpec:
    """Settings of the MediaPipe keypointer: the fields of config ``perception.pretrained.
    keypoints`` (their defaults and meaning live in the perception schema) and the cache."""

    cache: str
    track: bool
    hands: bool
    face: bool
    min_detection_score: float
    min_pose_presence: float
    min_wrist_visibility: float
    min_hand_presence: float
    hand_track_reach: float
    hand_track_trust: float
    palm_search: float
    min_palm_score: float
    still_hand_ratio: float
    min_face_detection_score: float
    min_face_presence: float
    min_score: float
    heatmap_kernel: int
    #: 'auto' (CUDA when onnxruntime has it), 'cpu' or 'cuda[:N]': the stage's --device
    device: str
    #: the hands looked for (with ``hands``): both for the whole body; the fingers of one
    #: side beside another keypointer (:mod:`signsplat.perception.hands`) need only that side
    hand_sides: tuple[str, ...]

    @classmethod
    def from_config(cls, pretrained: dict, device: str = "auto", **override) -> MediaPipeSpec:
        """From a validated ``perception.pretrained`` section, run on ``device``
        (``override`` replaces fields)."""
        fields = {"cache": pretrained["cache"], **pretrained["keypoints"], "device": device,
                  "hand_sides": tuple(POSE_HAND_POINTS), **override}
        return cls(**fields)


@dataclass
class PoseOutput:
    """The pose model's output in image pixels: landmarks (39, 2) (33 BlazePose points, then
    the auxiliary ones), visibility (39,), presence, segmentation logits (256, 256) of the
    crop ``roi``."""

    points: np.ndarray
    visibility: np.ndarray
    presence: float
    segmentation: np.ndarray
    roi: mp.Roi


@dataclass
class FrameDebug:
    """What the keypointer did on a frame (for overlays and the tables)."""

    persons: mp.Detections | None = None
    pose_roi: mp.Roi | None = None
    tracked: bool = False
    not_signer: int = 0  # poses found but not taken: nearer another person than the signer
    hand_rois: dict = field(default_factory=dict)
    hands_tracked: set = field(default_factory=set)
    hands_from_palm: set = field(default_factory=set)
    face_roi: mp.Roi | None = None


def _session(cache: str, name: str, size: int, threads: int, device: str):
    try:
        path = model_file(cache, name)
    except FetchError as exc:
        raise ModelContractError(str(exc)) from None
    sess = open_session(path, threads, f"{name} model", device)
    shape = list(sess.get_inputs()[0].shape)
    if shape != [1, 3, size, size]:
        raise ModelContractError(f"{path}: {name} expects input (1, 3, {size}, {size}), "
                                 f"found {tuple(shape)}")
    return sess


def tracked_hand_kept(hand_wrist, pose_wrist, pose_elbow, wrist_visibility: float,
                      reach: float, trust: float) -> bool:
    """Whether a hand found where the last frame's hand was belongs to this pose: its wrist
    lies within ``reach`` forearm lengths (pose wrist to elbow) of the pose's wrist, or the
    pose's wrist scores below ``trust`` and cannot tell."""
    if wrist_visibility < trust:
        return True
    forearm = float(np.linalg.norm(np.subtract(pose_wrist, pose_elbow)))
    gap = float(np.linalg.norm(np.subtract(hand_wrist, pose_wrist)))
    return bool(np.isfinite(gap)) and gap <= reach * forearm


def pose_is_signers(hip, signer_hip, others) -> bool:
    """Whether a pose whose mid-hip point is ``hip`` is the signer's, whom the segment stage
    chose at ``signer_hip``: no other detected person's mid-hip point (``others``, (M, 2);
    non-finite rows ignored) lies nearer to it. Where two people overlap, the pose model in
    the signer's region can return the other person's pose."""
    gap = float(np.linalg.norm(np.subtract(hip, signer_hip)))
    others = np.asarray(others if others is not None else [], np.float64).reshape(-1, 2)
    near = np.linalg.norm(others[np.isfinite(others).all(axis=1)] - np.asarray(hip), axis=1)
    return bool(np.isfinite(gap)) and bool((near >= gap).all())


class MediaPipeWholeBody:
    """Whole-body keypoints of one person per frame from MediaPipe's ONNX models in ``cache``.

    Call :meth:`detect` per frame in time order; :meth:`reset` forgets the tracked ROI (a new
    view or sequence). ``models`` are the models opened (all of :data:`MODELS` for the whole
    body; the hand landmark model alone serves :meth:`tracked_hand`).
    """

    def __init__(self, spec: MediaPipeSpec, threads: int = 1, models: tuple = MODELS):
        self.spec = spec
        self.sessions = {m["name"]: _session(spec.cache, m["name"], m["size"], threads,
                                             spec.device) for m in models}
        self.anchors = {m["name"]: mp.ssd_anchors(m["size"], m["strides"])
                        for m in (POSE_DET, PALM_DET, FACE_DET)}
        self.prev_roi: mp.Roi | None = None
        self.prev_hands: dict[str, np.ndarray] = {}  # side -> last frame's 21 hand points

    def reset(self) -> None:
        self.prev_roi = None
        self.prev_hands = {}

    def _run(self, model: dict, image: np.ndarray, roi: mp.Roi) -> tuple[list, mp.Roi]:
        """Crop ``roi`` (letterboxed to the input's aspect) and run ``model``; returns the
        outputs and the ROI actually cropped."""
        size = (model["size"], model["size"])
        roi, _ = mp.pad_roi(roi, size)
        x = mp.crop(image, roi, size, model["range"], model.get("border", "replicate"))
        sess = self.sessions[model["name"]]
        return sess.run(None, {sess.get_inputs()[0].name: x}), roi

    def _detect(self, model: dict, image: np.ndarray, roi: mp.Roi,
                min_score: float) -> mp.Detections:
        return self._detect_at(model, image, roi, (min_score,))[0]

    def _detect_at(self, model: dict, image: np.ndarray, roi: mp.Roi,
                   min_scores: tuple[float, ...]) -> list[mp.Detections]:
        """One run of a detector, decoded once per score threshold (each with its own
        suppression, so a threshold's detections do not depend on the others)."""
        (boxes, scores), roi = self._run(model, image, roi)
        size = model["size"]
        out = []
        for min_score in min_scores:
            det = mp.decode_detections(boxes[0], scores[0], self.anchors[model["name"]], size,
                                       model["keypoints"], min_score)
            out.append(mp.project_detections(mp.weighted_nms(det, NMS_IOU), roi, (size, size)))
        return out

    # --- stages ---------------------------------------------------------------------------

    def detect_persons(self, image: np.ndarray) -> mp.Detections:
        """Every person the pose detector finds in the whole frame (image pixels, best first);
        keypoints: mid-hip, full-body scale point, mid-shoulder, upper-body scale point."""
        return self.detect_persons_at(image, (self.spec.min_detection_score,))[0]

    def detect_persons_at(self, image: np.ndarray,
                          min_scores: tuple[float, ...]) -> list[mp.Detections]:
        """:meth:`detect_persons` at each of ``min_scores``, from one run of the detector."""
        h, w = image.shape[:2]
        return self._detect_at(POSE_DET, image, mp.Roi(w / 2, h / 2, w, h), min_scores)

    @staticmethod
    def person_roi(hip, scale_point) -> mp.Roi:
        """The pose model's ROI from a detection's (or the landmarks' auxiliary) points."""
        return mp.transform_roi(mp.alignment_roi(hip, scale_point, np.pi / 2), 1.25, 1.25)

    def pose(self, image: np.ndarray, roi: mp.Roi) -> PoseOutput:
        """The pose model in ``roi``: 39 landmarks, visibility, presence, segmentation."""
        outs, roi = self._run(POSE_LMK, image, roi)
        size = POSE_LMK["size"]
        raw = outs[0].reshape(39, 5).astype(np.float64)
        pts = raw[:, :2]
        if self.spec.heatmap_kernel > 0:
            pts = mp.refine_from_heatmap(pts, outs[3][0], (size, size), self.spec.heatmap_kernel)
        return PoseOutput(mp.crop_to_image(pts, roi, (size, size)), mp.sigmoid(raw[:, 3]),
                          float(np.ravel(outs[1])[0]), outs[2][0, 0], roi)

    def hand(self, image: np.ndarray, wrist, pinky, index) -> tuple[HandResult, mp.Roi]:
        """One hand's landmarks from the pose's wrist, pinky and index points."""
        wrist = np.asarray(wrist, float)
        middle = (2 * np.asarray(index, float) + np.asarray(pinky, float)) / 3
        # centre at the estimated middle finger, side twice its distance to the wrist
        side = 2 * float(np.linalg.norm(middle - wrist))
        loose = mp.Roi(float(middle[0]), float(middle[1]), side, side,
                       mp.rotation_between(wrist, middle, np.pi / 2))
        loose = mp.transform_roi(loose, 2.7, 2.7, shift_y=-0.1)
        outs, roi = self._run(HAND_RECROP, image, loose)
        size = HAND_RECROP["size"]
        p = mp.crop_to_image(np.ravel(outs[0]).reshape(2, 2).astype(np.float64), roi,
                             (size, size))
        tight = mp.transform_roi(mp.alignment_roi(p[0], p[1], -np.pi / 2), 1.0, 1.0,
                                 shift_y=-0.1)
        return self.hand_in(image, tight)

    def tracked_hand(self, image: np.ndarray, last: np.ndarray) -> tuple[HandResult, mp.Roi]:
        """One hand's landmarks in the ROI of the last frame's 21 points ``last``."""
        roi = mp.transform_roi(mp.hand_landmarks_roi(last), 2.0, 2.0, shift_y=-0.1)
        return self.hand_in(image, roi)

    def palm_hands(self, image: np.ndarray, centre, side: float
                   ) -> list[tuple[HandResult, mp.Roi]]:
        """The hand landmark model in the region of every palm the palm detector finds in a
        square of ``side`` pixels around ``centre``."""
        search = mp.Roi(float(centre[0]), float(centre[1]), side, side, 0.0)
        det = self._detect(PALM_DET, image, search, self.spec.min_palm_score)
        out = []
        for box, kps in zip(det.boxes, det.keypoints):
            roi = mp.box_roi(box.reshape(2, 2), mp.rotation_between(kps[0], kps[2], np.pi / 2))
            out.append(self.hand_in(image, mp.transform_roi(roi, 2.6, 2.6, shift_y=-0.5)))
        return out

    def hand_in(self, image: np.ndarray, roi: mp.Roi) -> tuple[HandResult, mp.Roi]:
        """The hand landmark model in ``roi``: 21 points, presence, handedness."""
        outs, roi = self._run(HAND_LMK, image, roi)
        size = HAND_LMK["size"]
        pts = mp.crop_to_image(outs[0].reshape(21, 3)[:, :2].astype(np.float64), roi,
                               (size, size))
        presence = float(np.ravel(outs[1])[0])
        left = left_hand_prob(float(np.ravel(outs[2])[0]))
        return HandResult(pts, presence, left), roi

    def face(self, image: np.ndarray, pose_face: np.ndarray) -> tuple[np.ndarray | None, float,
                                                                     mp.Roi | None]:
        """468 face-mesh points, presence probability and the face ROI (None when the face
        detector finds no face around the pose's face points)."""
        rot = mp.rotation_between(pose_face[POSE_RIGHT_EYE], pose_face[POSE_LEFT_EYE], 0.0)
        search = mp.transform_roi(mp.box_roi(pose_face, rot), 3.0, 3.0)
        det = self._detect(FACE_DET, image, search, self.spec.min_face_detection_score)
        if not len(det):
            return None, 0.0, None
        # the face whose nose tip is nearest the pose's nose (MediaPipe takes the best-scored
        # one, which in a crowd can be a neighbour's face inside the search region)
        kps = det.keypoints[int(np.argmin(np.linalg.norm(det.keypoints[:, 2] - pose_face[0],
                                                         axis=1)))]
        rot = mp.rotation_between(kps[0], kps[1], 0.0)
        roi = mp.transform_roi(mp.box_roi(kps, rot), 2.0, 2.0, shift_y=-0.1)
        outs, roi = self._run(FACE_LMK, image, roi)
        size = FACE_LMK["size"]
        pts = mp.crop_to_image(np.ravel(outs[0]).reshape(468, 3)[:, :2].astype(np.float64),
                               roi, (size, size))
        return pts, float(mp.sigmoid(np.ravel(outs[1])[0])), roi

    # --- one frame ------------------------------------------------------------------------

    def detect_one(self, image: np.ndarray, person=None) -> tuple[WholeBodyResult | None,
                                                                  FrameDebug]:
        """Landmarks of one person in an RGB uint8 frame, or None when there is none.

        ``person``: the signer's mid-hip and full-body size points (2, 2) from the segment
        stage's choice, optionally followed by the other detected people's ((1 + M, 2, 2));
        without it the detector's best-scored person. The ROI tracked from the last frame is
        tried first when its centre lies within a quarter of the person's body size of the
        person's mid-hip point (always, without ``person``), then the person's own ROI. With
        other people given, a pose nearer to one of them than to the signer is not taken
        (:func:`pose_is_signers`): the frame then has no keypoints rather than another
        person's."""
        s = self.spec
        dbg = FrameDebug()
        start = signer_hip = others = None
        if person is not None:
            people = np.asarray(person, np.float64).reshape(-1, 2, 2)
            start = self.person_roi(people[0, 0], people[0, 1])
            signer_hip, others = people[0, 0], people[1:, 0]
        rois = []
        if s.track and self.prev_roi is not None and (
                start is None or np.hypot(self.prev_roi.cx - start.cx,
                                          self.prev_roi.cy - start.cy) < start.w / 1.25 / 4):
            rois.append((True, self.prev_roi))
        if start is None and not rois:
            dbg.persons = self.detect_persons(image)
            if len(dbg.persons):
                kp = dbg.persons.keypoints[0]
                start = self.person_roi(kp[0], kp[1])
        if start is not None:
            rois.append((False, start))
        result = None
        for tracked, roi in rois:
            dbg.tracked = tracked
            result = self._pose_in(image, roi, dbg)
            if result is not None and others is not None and not pose_is_signers(
                    result.pose[list(POSE_HIPS)].mean(0), signer_hip, others):
                dbg.not_signer += 1
                result = None
            if result is not None:
                break
        if result is None:
            self.prev_roi = None
            self.prev_hands = {}
            return None, dbg
        if s.hands:
            for side in s.hand_sides:
                result.hands[side] = self._hand_of(image, result, side, dbg)
                if result.hands[side] is None:
                    self.prev_hands.pop(side, None)
                else:
                    self.prev_hands[side] = result.hands[side].points
        if s.face:
            pts, presence, roi = self.face(image, result.pose[list(POSE_FACE_POINTS)])
            dbg.face_roi = roi
            if pts is not None and presence >= s.min_face_presence:
                result.face, result.face_presence = pts, presence
        return result, dbg

    def _hand_of(self, image, result: WholeBodyResult, side: str,
                 dbg: FrameDebug) -> HandResult | None:
        """The ``side`` hand of the pose ``result``: from the pose's region, else tracked, else
        from a palm near the pose's wrist."""
        s = self.spec
        w, p, i = POSE_HAND_POINTS[side]
        vis = float(result.pose_visibility[w])
        if vis < s.min_wrist_visibility:
            return None
        hand, dbg.hand_rois[side] = self.hand(image, result.pose[w], result.pose[p],
                                              result.pose[i])
        if hand.presence >= s.min_hand_presence:
            return hand
        last = self.prev_hands.get(side)
        if s.track and s.hand_track_reach > 0 and last is not None:
            hand, roi = self.tracked_hand(image, last)
            if hand.presence >= s.min_hand_presence and tracked_hand_kept(
                    hand.points[0], result.pose[w], result.pose[POSE_ELBOW[side]], vis,
                    s.hand_track_reach, s.hand_track_trust):
                dbg.hand_rois[side] = roi
                dbg.hands_tracked.add(side)
                return hand
        if s.palm_search > 0 and dbg.pose_roi is not None:
            found = [(h, r) for h, r in self.palm_hands(image, result.pose[w],
                                                        s.palm_search * dbg.pose_roi.w)
                     if h.presence >= s.min_hand_presence]
            if found:
                hand, dbg.hand_rois[side] = min(
                    found, key=lambda hr: float(np.linalg.norm(hr[0].points[0] - result.pose[w])))
                dbg.hands_from_palm.add(side)
                return hand
        return None

    def _pose_in(self, image, roi: mp.Roi, dbg: FrameDebug) -> WholeBodyResult | None:
        out = self.pose(image, roi)
        if out.presence < self.spec.min_pose_presence:
            self.prev_roi = None
            return None
        dbg.pose_roi = roi
        self.prev_roi = self.person_roi(out.points[33], out.points[34])
        return WholeBodyResult(out.points[:33], out.visibility[:33], {})

    def detect(self, image: np.ndarray, person=None) -> tuple[np.ndarray, np.ndarray]:
        """COCO-WholeBody (133, 2) pixels (NaN = none) and (133,) scores of one frame."""
        result, _ = self.detect_one(image, person)
        return to_coco_wholebody(result, self.spec.min_score)


class MediaPipeKeypointer:
    """:class:`MediaPipeWholeBody` behind the stages' keypointer interface (``detect(images,
    boxes, views)``): frames come in time order per view; tracking restarts at a new view and
    after a frame without a person (an empty mask: ``box`` None)."""

    source = "mediapipe"
    batch_size = 8  # frames read per chunk (the models run one crop at a time)
    min_area = 0
    num_keypoints = NUM_KEYPOINTS

    def __init__(self, spec: MediaPipeSpec, threads: int = 1):
        self.model = MediaPipeWholeBody(spec, threads)
        self.path = str(spec.cache)
        self._view = None
        self.not_signer = 0  # frames left without keypoints: the pose was another person's

    def detect(self, images: list, boxes: list, views: list[int], persons: list | None = None):
        """Keypoints per frame; ``persons`` (per frame the chosen signer's mid-hip and size
        points, then the other detected people's, (1 + M, 2, 2), or None) come from the segment
        stage's persons table."""
        n = len(images)
        xy = np.full((n, NUM_KEYPOINTS, 2), np.nan, np.float32)
        sc = np.zeros((n, NUM_KEYPOINTS), np.float32)
        persons = persons if persons is not None else [None] * n
        for i, (image, box, view) in enumerate(zip(images, boxes, views, strict=True)):
            if view != self._view or box is None:
                self.model.reset()
                self._view = view
            if box is None:
                continue
            result, dbg = self.model.detect_one(image, persons[i])
            self.not_signer += result is None and dbg.not_signer > 0
            xy[i], sc[i] = to_coco_wholebody(result, self.model.spec.min_score)
        return xy, sc

    def finish(self, frames: np.ndarray, xy: np.ndarray, sc: np.ndarray
               ) -> tuple[np.ndarray, np.ndarray, dict[str, int]]:
        """One view's keypoints (frame order) after its last frame, with the hands of still
        tracks cleared, and per side the frames cleared."""
        s = self.model.spec
        return drop_still_hands(frames, xy, sc, ratio=s.still_hand_ratio,
                                min_score=s.min_hand_presence, trust=s.hand_track_trust)

    def summary(self) -> str:
        """Frames left without keypoints because the only pose found was another person's
        (beside ``finish``'s per-view counts), for the stage's log."""
        if not self.not_signer:
            return ""
        return (f"{self.not_signer} frame(s) without keypoints: the pose found in the signer's "
                "region was nearer another person (people overlapping)")
