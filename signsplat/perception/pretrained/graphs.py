"""The pretrained keypointer's models and their facts from MediaPipe's graphs (input size,
value range, crop border, SSD strides), in a module of their own without heavy imports: the
workflow names the model files as inputs while Snakemake parses it."""

POSE_DET = dict(name="pose_detection", size=224, range=(-1.0, 1.0), border="zero",
                strides=(8, 16, 32, 32, 32), keypoints=4)
POSE_LMK = dict(name="pose_landmark_full", size=256, range=(0.0, 1.0))
HAND_RECROP = dict(name="hand_recrop", size=256, range=(0.0, 1.0))
HAND_LMK = dict(name="hand_landmark_full", size=224, range=(0.0, 1.0))
PALM_DET = dict(name="palm_detection_full", size=192, range=(0.0, 1.0), border="zero",
                strides=(8, 16, 16, 16), keypoints=7)
FACE_DET = dict(name="face_detection_short_range", size=128, range=(-1.0, 1.0), border="zero",
                strides=(8, 16, 16, 16), keypoints=6)
FACE_LMK = dict(name="face_landmark", size=192, range=(0.0, 1.0))
MODELS = (POSE_DET, POSE_LMK, HAND_RECROP, HAND_LMK, PALM_DET, FACE_DET, FACE_LMK)
