"""COLMAP (pycolmap 4.x) reconstructions of a scene's images, compared with the SMPL-X camera solve.

- :mod:`run`: one SfM run (SIFT, exhaustive matching, incremental mapping), failures recorded.
- :mod:`align`: similarity alignment to ground-truth cameras, rotation / centre errors.
- :mod:`compare`: planning the runs of a scene and building ``colmap_compare.parquet``.
- :mod:`ply`: COLMAP points as a standard PLY (baseline splat initialisation).
"""
