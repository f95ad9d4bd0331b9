"""Pretrained real-world detectors from registry wheels: fetch and conversion (``fetch``,
``convert``), MediaPipe's geometry (``mediapipe``), its whole-body keypointer (``keypointer``)
and the mapping of its landmarks to COCO-WholeBody 133 (``wholebody``). MODNet runs through
the MODNet-style segmenter contract (``signsplat.perception.contracts``)."""
