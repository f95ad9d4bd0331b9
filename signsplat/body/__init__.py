"""Body model: SMPL-X-layout files, LBS in torch, the procedural proxy, keypoint regressor.

Modules: ``model_file`` (checked .npz loading/writing), ``model`` (:class:`BodyModel`),
``params`` (tables <-> tensors), ``proxy`` (procedural proxy model), ``appearance``
(procedural albedo), ``keypoints`` (COCO-WholeBody 133 regressor), ``joints`` (layouts),
``hand_limits`` (finger joint limits).
"""
