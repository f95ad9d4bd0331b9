"""The avatar metrics table: each mean over a split's images with its standard error."""

import numpy as np
import pandas as pd

from signsplat.avatar.config import avatar_config
from signsplat.avatar.evaluate import summarize


def test_metrics_carry_the_standard_error_of_their_mean_over_the_images():
    """summarize: the mean over a split's images and its standard error (sd / sqrt(n)); one
    image has none (NaN), not a zero that would read as a certain figure."""
    rows = [("novel_pose", "full", v) for v in (30.0, 32.0, 34.0, 28.0)] \
        + [("train", "full", 31.0)]
    per_image = pd.DataFrame([{"split": s, "protocol": "bg_replaced", "refine": False,
                               "part": p, "metric": "psnr", "value": v} for s, p, v in rows])
    m = summarize(per_image, "s", "demo", 10.0, avatar_config({}), 1.0, "fitted")
    held = m[m.split == "novel_pose"].iloc[0]
    assert held.value == 31.0 and held.n_images == 4
    assert np.isclose(held.std_error, np.std([30, 32, 34, 28], ddof=1) / 2)
    one = m[m.split == "train"].iloc[0]
    assert one.n_images == 1 and np.isnan(one.std_error)
