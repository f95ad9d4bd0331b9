"""The forward kernel evaluates, per tile and Gaussian, only the rows of ``_tile_rows``: every
pixel it leaves out must have alpha < 1/255, for round, sheared and needle-thin ellipses, at
every position relative to the tile (a row skipped wrongly would change the image)."""

from __future__ import annotations

import numpy as np
import pytest

from signsplat.render import _kernels as K
from signsplat.render._constants import ALPHA_THRESHOLD, MAX_ALPHA

TILE = K.TILE


def _alpha_rows(mx, my, ca, cb, cc, op, x0, y0, xw, yh):
    """Rows (tile-relative) holding a pixel with alpha >= 1/255, evaluated like the kernel
    (float32, d = mean - pixel centre)."""
    f = np.float32
    px = (np.arange(xw, dtype=f) + f(x0) + f(0.5))[None, :]
    py = (np.arange(yh, dtype=f) + f(y0) + f(0.5))[:, None]
    dx = f(mx) - px
    dy = f(my) - py
    sig = f(0.5) * (f(ca) * dx * dx + f(cc) * dy * dy) + f(cb) * dx * dy
    al = np.minimum(f(MAX_ALPHA), f(op) * np.exp(-sig))
    hit = (sig >= 0) & (al >= f(ALPHA_THRESHOLD))
    return np.flatnonzero(hit.any(1))


def _random_gaussian(rng):
    """A 2D covariance (dilated like the projection's), its conic and an opacity."""
    s1, s2 = np.exp(rng.uniform(np.log(0.05), np.log(30.0), 2))
    th = rng.uniform(0, np.pi)
    R = np.array([[np.cos(th), -np.sin(th)], [np.sin(th), np.cos(th)]])
    cov = R @ np.diag([s1 * s1, s2 * s2]) @ R.T + 0.3 * np.eye(2)
    con = np.linalg.inv(cov)
    op = rng.choice([rng.uniform(0.004, 1.0), 1.0, 0.0045])
    return cov, (np.float32(con[0, 0]), np.float32(con[0, 1]), np.float32(con[1, 1])), op


@pytest.mark.parametrize("seed", range(4))
def test_tile_rows_keep_every_pixel_with_alpha(seed):
    rng = np.random.default_rng(seed)
    skipped_rows = 0
    for _ in range(400):
        cov, (ca, cb, cc), op = _random_gaussian(rng)
        # radius as the projection computes it (3.33 sigma at most)
        ext = min(3.33, np.sqrt(2 * np.log(max(op, ALPHA_THRESHOLD) / ALPHA_THRESHOLD)))
        ry = int(np.ceil(ext * np.sqrt(cov[1, 1])))
        x0, y0 = 16 * rng.integers(0, 4), 16 * rng.integers(0, 4)
        xw = TILE if rng.random() < 0.8 else int(rng.integers(1, TILE))  # image's last column
        height = 64
        # centres inside, beside and at the corners of the tile
        mx = np.float32(x0 + rng.uniform(-40, 56))
        my = np.float32(y0 + rng.uniform(-40, 56))
        level, hy = K._row_params(np.float32(op), ca, cb, cc)
        lo, hi = K._tile_rows(float(mx), float(my), ry, ca, cb, cc, level, hy, x0, xw, y0,
                              height)
        box_lo, box_hi = K._row_range(float(my), ry, y0, height)
        assert box_lo <= lo or lo >= hi  # never more than the bounding box
        assert hi <= box_hi or lo >= hi
        rows = _alpha_rows(mx, my, ca, cb, cc, op, x0, y0, xw, min(TILE, height - y0))
        # rows with alpha >= 1/255 inside the bounding box must all be kept
        in_box = rows[(rows >= box_lo) & (rows < box_hi)]
        assert np.all((in_box >= lo) & (in_box < hi)), (mx, my, ca, cb, cc, op, lo, hi, rows)
        skipped_rows += max(0, box_hi - box_lo) - max(0, hi - lo)
    assert skipped_rows > 0  # the test exercised the cut (it is not just the box)
