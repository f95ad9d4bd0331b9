"""SignSplat: sign-language video to a drivable Gaussian-splat avatar on an SMPL-X body.

The library is a set of small modules with functional cores; the Snakemake workflow in
``workflow/`` calls them through ``signsplat.cli``. See README.md for the stage map.
"""

__version__ = "0.1.0"

import os as _os

# GNU OpenMP (torch's and Numba's thread pools) spins for a long time after each parallel region
# by default; on a shared 2-core machine a spinning thread holds the core its partner needs
# (measured: a training step used 0.72 s of CPU with 2 Numba threads against 0.48 s with a short
# spin). It must be set before torch loads libgomp, hence here; the user's own setting wins.
if "OMP_WAIT_POLICY" not in _os.environ and "GOMP_SPINCOUNT" not in _os.environ:
    _os.environ["GOMP_SPINCOUNT"] = "10000"
