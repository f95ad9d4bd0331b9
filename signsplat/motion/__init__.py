"""Gloss clips and their stitching into continuous motion (used by ``synth`` and ``stitch``).

Modules: :mod:`signsplat.motion.clips` (the clip and its table),
:mod:`signsplat.motion.stitching` (SLERP transitions between clips, paper section 3.6).
"""
