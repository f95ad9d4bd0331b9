"""Where the signing hand's held-out PSNR goes: the avatar trained on the fit, on the truth, and
on mixtures of the two that swap one part of the signing arm.

On a finished run of a synthetic sequence (``make demo``'s results), the demo avatar is trained
and evaluated again on SMPL-X tables that mix the fit's parameters with the simulator's:

- ``truth``: the simulator's SMPL-X and cameras (what the avatar reaches with no fit error);
- ``truth_fit_fingers``: the truth with the fit's finger pose of the signing hand;
- ``truth_fit_arm``: the truth with the fit's signing arm (collar, shoulder, elbow and wrist
  angles) and fingers;
- ``fit_true_fingers``, ``fit_true_arm``: the fit (its cameras) with the truth's fingers, or
  arm and fingers, of the signing hand;
- ``fit_true_head``, ``fit_true_head_arm``: the fit with the truth's head (neck and head
  angles, jaw, eyes and expression; the face is behind the signing hand in most crops), alone
  or with the signing arm and fingers;
- ``fit_true_shape``, ``fit_true_head_arm_shape``: the fit with the truth's body shape
  (``betas``), alone or with the head, the signing arm and fingers;
- ``truth_fit_fingers_offset``: the truth with the fit's mean error of the signing hand's
  fingers (over the frames) added: the part of their error that does not change;
- ``truth_fit_fingers_varying``: the truth with the fit's fingers less that mean error: the
  part that changes from frame to frame;
- ``truth_fit_fingers_but_thumb``: the truth with the fit's fingers of the signing hand but
  the true thumb;
- ``--fits name=folder``: another fit folder of the same scene (e.g. one fitted with the
  cameras held at their calibration), as it is.

The fit's own avatar is the run's ``eval/demo`` (pass ``--fitted`` to train it again). Each
training is the command the workflow runs, with the demo variant's resolved config, one thread
per job, ``--jobs`` at a time; ``--iterations N`` trains every run, the fit's own too, for N
steps instead of the demo profile's; ``--no-finetune`` trains every run on its SMPL-X table as
it is (``train.finetune_smplx`` off); ``--train KEY=VALUE`` sets any other training setting
(a JSON value, e.g. ``--train pose_knot_spacing=4 seed=1``).

    python benchmarks/hand_budget.py --results results --scene studio6 --hand right \
        --work /tmp/budget --out benchmarks/results/hand_budget.parquet

Prints PSNR per run, split and part (background replaced, no refinement); ``--out`` saves them.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import pandas as pd
import yaml

from signsplat.body.joints import JOINT_INDEX
from signsplat.config import load_config
from signsplat.plan import plan

ARM = ("collar", "shoulder", "elbow", "wrist")
HEAD_JOINTS = ("neck", "head")
HEAD_COLUMNS = ("jaw_pose", "leye_pose", "reye_pose", "expression")
MIXES = {  # name: (base, donor, donor's parts)
    "truth": ("truth", None, ()),
    "truth_fit_fingers": ("truth", "fit", ("fingers",)),
    "truth_fit_arm": ("truth", "fit", ("fingers", "arm")),
    "fit_true_fingers": ("fit", "truth", ("fingers",)),
    "fit_true_arm": ("fit", "truth", ("fingers", "arm")),
    "fit_true_head": ("fit", "truth", ("head",)),
    "fit_true_head_arm": ("fit", "truth", ("head", "fingers", "arm")),
    "fit_true_shape": ("fit", "truth", ("shape",)),
    "fit_true_head_arm_shape": ("fit", "truth", ("head", "fingers", "arm", "shape")),
    "truth_fit_fingers_offset": ("truth", "fit", ("fingers_offset",)),
    "truth_fit_fingers_varying": ("truth", "fit", ("fingers_varying",)),
    "truth_fit_fingers_but_thumb": ("truth", "fit", ("fingers_but_thumb",)),
}
THUMB = slice(36, 45)  # the last three of a hand pose's 15 joints (3 values each)


def mix(base: pd.DataFrame, donor: pd.DataFrame, parts: tuple[str, ...], hand: str
        ) -> pd.DataFrame:
    """``base`` with ``donor``'s finger pose, arm angles (of one side), head and/or shape,
    frame by frame (both tables sorted by frame, the same frames). ``fingers_offset`` adds to
    ``base``'s fingers only the mean over the frames of ``donor``'s difference from them;
    ``fingers_varying`` takes ``donor``'s fingers less that mean difference;
    ``fingers_but_thumb`` takes ``donor``'s fingers but keeps ``base``'s thumb."""
    out = base.copy()
    if "shape" in parts:
        out["betas"] = list(donor["betas"])
    column = f"{hand}_hand_pose"
    if "fingers" in parts:
        out[column] = list(donor[column])
    if {"fingers_offset", "fingers_varying"} & set(parts):
        ours = np.stack(base[column]).astype(np.float64)
        theirs = np.stack(donor[column]).astype(np.float64)
        offset = (theirs - ours).mean(0)
        out[column] = list(ours + offset if "fingers_offset" in parts else theirs - offset)
    if "fingers_but_thumb" in parts:
        fingers = np.stack(donor[column]).astype(np.float64)
        fingers[:, THUMB] = np.stack(base[column])[:, THUMB]
        out[column] = list(fingers)
    if "head" in parts:
        for col in HEAD_COLUMNS:
            out[col] = list(donor[col])
    joints = ([f"{hand}_{j}" for j in ARM] if "arm" in parts else []) + \
        (list(HEAD_JOINTS) if "head" in parts else [])
    if joints:
        # body_pose holds the joints after the pelvis, three values each
        slots = [JOINT_INDEX[j] - 1 for j in joints]
        poses = []
        for a, b in zip(base["body_pose"], donor["body_pose"]):
            a = np.asarray(a, np.float64).reshape(-1, 3).copy()
            a[slots] = np.asarray(b, np.float64).reshape(-1, 3)[slots]
            poses.append(a.ravel())
        out["body_pose"] = poses
    return out


def demo_sections(config: str, scene: str, settings: dict | None = None) -> tuple[str, str]:
    """The demo variant's train and eval config of ``scene``, as the workflow passes them,
    with ``settings`` replacing keys of its ``train`` section (e.g. ``iterations``)."""
    user = yaml.safe_load(Path(config).read_text()) or {}
    p = plan(load_config(config), user)
    train = p.train_section("demo", scene)
    unknown = sorted(set(settings or {}) - set(train["train"]))
    if unknown:
        raise SystemExit(f"--train {', '.join(unknown)}: not a training setting; the settings "
                         f"are {', '.join(sorted(train['train']))}")
    train["train"].update(settings or {})
    return json.dumps(train), json.dumps(p.eval_section("demo", scene))


def train_and_score(name: str, smplx: Path, cameras: Path, common: list[str], cfgs, work: Path,
                    ) -> Path:
    train_cfg, eval_cfg = cfgs
    out = work / name
    out.mkdir(parents=True, exist_ok=True)
    py = [sys.executable, "-m", "signsplat"]
    args = common + ["--cameras", str(cameras), "--smplx", str(smplx), "--variant", "demo",
                     "--threads", "1", "--device", "cpu"]
    with open(out / "train.log", "w") as log:
        subprocess.run(py + ["train-avatar", *args, "--config-json", train_cfg, "--out",
                             str(out / "avatar"), "--no-progress"],
                       check=True, stdout=log, stderr=subprocess.STDOUT)
    with open(out / "eval.log", "w") as log:
        subprocess.run(py + ["evaluate-avatar", *args, "--config-json", eval_cfg,
                             "--checkpoint", str(out / "avatar" / "checkpoint.pt"),
                             "--out", str(out / "eval")],
                       check=True, stdout=log, stderr=subprocess.STDOUT)
    return out / "eval" / "metrics.parquet"


def scores(name: str, metrics: Path) -> pd.DataFrame:
    m = pd.read_parquet(metrics)
    m = m[(m.metric == "psnr") & (m.protocol == "bg_replaced")]
    return m.assign(run=name)[["run", "split", "part", "value", "std_error", "train_seconds"]]


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--results", required=True, help="a finished run's results folder")
    p.add_argument("--scene", default="studio6")
    p.add_argument("--hand", choices=("left", "right"), default="right",
                   help="the signing hand")
    p.add_argument("--config", default="config/config.yaml")
    p.add_argument("--runs", nargs="*", default=list(MIXES), choices=list(MIXES),
                   help="the mixes to train (none: only the fit's own, with --fitted)")
    p.add_argument("--fits", nargs="*", default=[], metavar="NAME=FOLDER")
    p.add_argument("--fitted", action="store_true", help="train the fit's own avatar again")
    p.add_argument("--iterations", type=int,
                   help="training steps instead of the demo profile's (implies --fitted)")
    p.add_argument("--no-finetune", dest="finetune", action="store_false",
                   help="train on the SMPL-X tables as they are, without fine-tuning them "
                        "(implies --fitted)")
    p.add_argument("--train", nargs="*", default=[], metavar="KEY=VALUE",
                   help="other training settings, JSON values (implies --fitted)")
    p.add_argument("--work", required=True, help="folder for the avatars")
    p.add_argument("--jobs", type=int, default=2)
    p.add_argument("--out")
    args = p.parse_args()
    if args.iterations is not None and args.iterations < 1:
        raise SystemExit(f"--iterations {args.iterations}: give a step count >= 1")
    settings = {} if args.iterations is None else {"iterations": args.iterations}
    if not args.finetune:
        settings["finetune_smplx"] = False
    for spec in args.train:
        key, sep, value = spec.partition("=")
        try:
            settings[key] = json.loads(value)
        except json.JSONDecodeError:
            sep = ""
        if not (key and sep):
            raise SystemExit(f"--train {spec!r}: give KEY=VALUE with a JSON value")
    if settings:
        args.fitted = True  # make demo's own avatar has the demo profile's settings, not these
    if not (args.runs or args.fitted or args.fits):
        raise SystemExit("nothing to train: give --runs, --fits or --fitted")

    res = Path(args.results) / args.scene
    sim, fit = res / "sim", res / "fit"
    demo = res / "eval" / "demo" / "metrics.parquet"
    needed = [sim / "smplx_gt.parquet", fit / "smplx_fit.parquet"] + ([] if args.fitted else [demo])
    missing = [str(f) for f in needed if not f.exists()]
    if missing:
        raise SystemExit(f"missing {', '.join(missing)}: run `make demo` first (or pass --fitted "
                         "to train the fit's avatar here too)")
    tables = {"truth": pd.read_parquet(sim / "smplx_gt.parquet").sort_values("frame"),
              "fit": pd.read_parquet(fit / "smplx_fit.parquet").sort_values("frame")}
    if not np.array_equal(tables["truth"]["frame"].to_numpy(), tables["fit"]["frame"].to_numpy()):
        raise SystemExit(f"{fit}: the fit's frames are not the simulation's")
    cams = {"truth": sim / "cameras.parquet", "fit": fit / "cameras_fit.parquet"}
    jobs = {}
    for spec in args.fits:
        name, sep, folder = spec.partition("=")
        if not (name and sep and (Path(folder) / "smplx_fit.parquet").exists()):
            raise SystemExit(f"--fits {spec!r}: give NAME=FOLDER, a fit folder with "
                             "smplx_fit.parquet and cameras_fit.parquet")
        jobs[name] = (Path(folder) / "smplx_fit.parquet", Path(folder) / "cameras_fit.parquet")
    work = Path(args.work)
    work.mkdir(parents=True, exist_ok=True)
    for name in args.runs:
        base, donor, parts = MIXES[name]
        table = tables[base] if donor is None else mix(tables[base], tables[donor], parts,
                                                       args.hand)
        path = work / f"{name}.parquet"
        table.to_parquet(path)
        jobs[name] = (path, cams[base])
    if args.fitted:
        jobs["fit"] = (fit / "smplx_fit.parquet", cams["fit"])
    common = ["--body", str(Path(args.results) / "_assets" / "body_model.npz"),
              "--frames", str(sim / "frames.parquet")]
    cfgs = demo_sections(args.config, args.scene, settings)
    with ThreadPoolExecutor(args.jobs) as pool:
        done = {n: pool.submit(train_and_score, n, s, c, common, cfgs, work)
                for n, (s, c) in jobs.items()}
    frames = [scores(n, f.result()) for n, f in done.items()]
    if not args.fitted:
        frames.insert(0, scores("fit", demo))
    train = json.loads(cfgs[0])["train"]
    table = pd.concat(frames, ignore_index=True).assign(
        scene=args.scene, hand=args.hand, iterations=train["iterations"],
        finetune_smplx=train["finetune_smplx"], lr_smplx=train["lr_smplx"],
        settings=json.dumps(settings, sort_keys=True))
    wide = table.pivot_table(index=["run", "split"], columns="part", values="value",
                             sort=False).round(2)
    print(wide.to_string())
    if args.out:
        table.to_parquet(args.out)


if __name__ == "__main__":
    main()
