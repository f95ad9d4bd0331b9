"""SignSplat: sign-language video to a drivable Gaussian-splat avatar on an SMPL-X body.

The library is a set of small modules with functional cores; the Snakemake workflow in
``workflow/`` calls them through ``signsplat.cli``. See README.md for the stage map.
"""

__version__ = "0.1.0"
