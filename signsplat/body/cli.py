"""``signsplat body-model``: write the body model used by every later stage.

``signsplat body-model --config-json '<body_model section>' --out results/_assets/body_model.npz``

With ``path: null`` the procedural proxy (seed ``proxy_seed``) is generated; with a path the
file is loaded, checked (keys, shapes, a forward pass) and copied to ``--out``.
"""

from __future__ import annotations

import argparse
import shutil
import time
from pathlib import Path

from signsplat.config import config_option
from signsplat.errors import InputError
from signsplat.io.atomic import atomic_path


def body_model(argv: list[str]) -> int:
    """Entry point of ``signsplat body-model`` (argv without the command name)."""
    parser = argparse.ArgumentParser(prog="signsplat body-model",
                                     description="Write the body model (.npz, SMPL-X layout).")
    parser.add_argument("--config-json", default="{}",
                        help="the body_model config section as JSON")
    parser.add_argument("--out", required=True, help="output .npz path")
    args = parser.parse_args(argv)
    cfg = config_option(args.config_json, "stages/body_model.schema.yaml")

    import torch

    from signsplat.body.model import BodyModel

    t0 = time.perf_counter()
    out = Path(args.out)
    if cfg["path"] is None:
        from signsplat.body.proxy import write_proxy_model

        write_proxy_model(out, seed=int(cfg["proxy_seed"]))
        what = f"procedural proxy (seed {cfg['proxy_seed']})"
    else:
        src = Path(cfg["path"]).expanduser()
        BodyModel.from_file(src)  # raises BodyModelFileError naming key and file
        with atomic_path(out, suffix=".npz") as tmp:
            shutil.copyfile(src, tmp)
        what = f"checked copy of {src}"
    model = BodyModel.from_file(out, num_betas=cfg["num_betas"],
                                num_expression=cfg["num_expression"])
    with torch.no_grad():
        res = model()
    if not torch.isfinite(res.vertices).all():
        raise InputError(f"{out}: the body model gives non-finite vertices in the rest pose")
    seconds = time.perf_counter() - t0
    height = float(res.vertices[0, :, 1].max() - res.vertices[0, :, 1].min())
    print(f"wrote {out}: {what}; {model.num_vertices} vertices, {model.faces.shape[0]} faces, "
          f"{model.num_betas} betas, {model.num_expression} expressions, height "
          f"{height:.3f} m; {seconds:.1f} s")
    return 0
