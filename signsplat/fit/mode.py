"""Which fit a scene gets: multi-view (cameras solved with the body) or single view.

One answer for the workflow (``workflow/rules/fit.smk`` passes each scene only the settings of
its mode, so a change to one mode's stages does not re-run the other's fits) and for the fit
itself (:func:`signsplat.fit.run.run_fit`). Imports nothing heavy: the Snakefile calls it at
parse time.
"""

from __future__ import annotations

from signsplat.errors import InputError

MODES = ("multiview", "singleview")


def fit_mode(cfg: dict, num_views: int) -> str:
    """``multiview`` or ``singleview`` for a scene with ``num_views`` cameras.

    ``cfg``: the validated ``fit`` section; its ``mode`` ``auto`` means multi-view from two
    cameras on. A forced ``multiview`` with one camera raises :class:`InputError`.
    """
    mode = cfg["mode"]
    if mode == "auto":
        return "multiview" if num_views > 1 else "singleview"
    if mode == "multiview" and num_views < 2:
        raise InputError(f"fit.mode multiview needs at least 2 cameras, the scene has "
                         f"{num_views}; use mode auto or singleview")
    return mode


def mode_config(cfg: dict, num_views: int) -> dict:
    """The ``fit`` section without the settings of the mode this scene does not use."""
    other = {"multiview": "singleview", "singleview": "multiview"}[fit_mode(cfg, num_views)]
    return {k: v for k, v in cfg.items() if k != other}
