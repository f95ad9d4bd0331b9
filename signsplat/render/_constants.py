"""Numerical constants shared by every backend, forward and backward (see the package docstring)."""

#: Contributions with ``alpha < ALPHA_THRESHOLD`` are skipped (gsplat/3DGS: 1/255).
ALPHA_THRESHOLD = 1.0 / 255.0
#: ``alpha = min(MAX_ALPHA, opacity * exp(-sigma))``.
MAX_ALPHA = 0.999
#: A pixel stops when compositing the next Gaussian would bring its transmittance to or below
#: this value; that Gaussian is not composited (gsplat's "exclusive" rule).
TRANSMITTANCE_THRESHOLD = 1e-4
#: Upper bound of the bounding-box extent in standard deviations (the opacity-aware extent
#: ``sqrt(2 log(opacity / ALPHA_THRESHOLD))`` is used when smaller; gsplat 1.5: 3.33).
MAX_EXTENT_SIGMA = 3.33
#: The EWA Jacobian is evaluated at ``x/z, y/z`` clamped to the image frustum widened by this
#: fraction of the half field of view on each side (3DGS/gsplat: 0.3, i.e. about 1.3x the FOV).
FOV_CLAMP_MARGIN = 0.3
#: Quaternions are normalised as ``q / sqrt(max(|q|^2, QUAT_EPS2))``: a zero quaternion becomes
#: the zero vector, whose rotation-matrix formula is the identity, with a zero gradient.
QUAT_EPS2 = 1e-24
#: Directions for spherical harmonics are normalised the same way.
DIR_EPS2 = 1e-24
#: Radii are clamped to this many pixels before the cast to int32.
MAX_RADIUS = 1.0e9
#: Default screen-space dilation ``eps2d`` in pixels^2 (gsplat's default); callers that render
#: above the resolution an avatar was trained at scale it (``signsplat.avatar.train.eval_eps2d``).
DEFAULT_EPS2D = 0.3
#: Tile edge used internally by the CPU kernel (results do not depend on the tile size).
CPU_TILE = 16
