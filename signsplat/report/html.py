"""The self-contained HTML report: ``reports/index.html`` with its images in ``reports/assets/``
(relative links, so the folder opens from disk with no server and no network).

One section per stage, built from :func:`signsplat.report.collect.collect`. A stage that did not
run gets a section saying so. Every figure carries its wall-clock seconds beside it (from the
Snakemake benchmark files, or the stage's own table when no benchmark exists).
"""

from __future__ import annotations

import hashlib
import re
from html import escape
import shutil
from dataclasses import dataclass, field
from pathlib import Path

import jinja2
import numpy as np
import pandas as pd

from signsplat.avatar.views import WEAK_VIEW_DB, weak_views
from signsplat.body import joints as J
from signsplat.io.atomic import atomic_path
from signsplat.io.images import read_rgb, write_png
from signsplat.report import accounting, plots, runs
from signsplat.report.collect import Results, bench_seconds, collect
from signsplat.report.fit_suite import fit_suite_section
from signsplat.report.fit_sweep import fit_sweep_section


@dataclass
class Figure:
    src: str  # path relative to the report
    caption: str
    seconds: float | None
    seconds_note: str  # what the seconds measure
    pixelated: bool = False


@dataclass
class Section:
    id: str
    title: str
    intro: str = ""
    missing: str = ""  # non-empty: the stage did not run, and why it is absent
    tables: list[tuple[str, str]] = field(default_factory=list)  # (caption, html)
    figures: list[Figure] = field(default_factory=list)
    frames: list[tuple[str, pd.DataFrame]] = field(default_factory=list)  # (caption, table)

    def add_table(self, caption: str, df: pd.DataFrame | None) -> None:
        """A table shown as HTML and kept for the TSV copies (``write_report(tables_dir=)``)."""
        self.tables.append((caption, table_html(df)))
        if df is not None and len(df):
            self.frames.append((caption, df))


class Assets:
    """Copies or writes images into ``assets/`` beside the report; returns relative links."""

    def __init__(self, report_dir: Path):
        self.dir = Path(report_dir) / "assets"
        self.dir.mkdir(parents=True, exist_ok=True)

    def name(self, key: str, suffix: str = ".png") -> Path:
        stem = re.sub(r"[^A-Za-z0-9_.-]+", "_", key)[-60:]
        return self.dir / f"{hashlib.sha1(key.encode()).hexdigest()[:8]}_{stem}{suffix}"

    def copy(self, src: Path) -> str:
        dst = self.name(str(Path(src).resolve().with_suffix("")), Path(src).suffix)
        with atomic_path(dst) as tmp:
            shutil.copyfile(src, tmp)
        return f"assets/{dst.name}"

    def path(self, key: str) -> Path:
        return self.name(key)

    def rel(self, path: Path) -> str:
        return f"assets/{Path(path).name}"


def table_html(df: pd.DataFrame | None, max_rows: int = 200) -> str:
    """A DataFrame as an HTML table (floats with 4 significant digits)."""
    if df is None or not len(df):
        return "<p class='missing'>no rows</p>"
    df = df.head(max_rows)
    return df.to_html(index=False, classes="data", border=0, na_rep="–",
                      float_format=lambda v: f"{v:.4g}", escape=True)


def _fmt_seconds(s: float | None) -> str:
    return "n/a" if s is None or not np.isfinite(s) else f"{s:.1f} s"


# --- sections ---------------------------------------------------------------------------------

def _effects(spec: dict | None) -> str:
    if not spec:
        return "scene spec not found"
    names = []
    for e in spec.get("effects", []):
        names.append(e if isinstance(e, str) else ", ".join(f"{k} {v}" for k, v in e.items()))
    return "; ".join(names) or "none"


def scene_section(res: Results, assets: Assets) -> Section:
    sec = Section("scene", "1. Scene and effects simulated")
    rows = []
    for name, t in res.scenes.items():
        if t.frames is None:
            continue
        cams = t.cameras
        size = (f"{int(cams['width'].iloc[0])}x{int(cams['height'].iloc[0])}"
                if cams is not None and len(cams) else "?")
        secs = bench_seconds(res.benchmarks, "simulate", name)
        rows.append({"scene": name, "views": t.frames["view"].nunique(),
                     "frames": t.frames["frame"].nunique(), "image size": size,
                     "effects": _effects(t.spec), "simulate seconds": secs})
        for img in t.sim_images:
            sec.figures.append(Figure(assets.copy(img), f"{name}: view {img.parent.name}, first "
                                      "frame", secs, "simulate (whole scene)"))
    if not rows:
        sec.missing = "no simulated or extracted frames found (stage 1 did not run)"
    else:
        sec.add_table("Sequences", pd.DataFrame(rows))
    return sec


def perception_section(res: Results) -> Section:
    sec = Section("perception", "2. Perception accuracy and speed",
                  "Mask IoU, PCK@0.05 and pixel error against the simulator's ground truth; "
                  "frames per second of each stage.")
    keypointers = [{"sequence": name, "keypointer": t.keypointer.get("source", ""),
                    "model": t.keypointer.get("model", ""), "note": t.keypointer.get("note", "")}
                   for name, t in res.scenes.items() if t.keypointer]
    if keypointers:
        sec.add_table("Keypoints: which keypointer and model, and what it reported",
                      pd.DataFrame(keypointers))
    for name, t in res.scenes.items():
        if t.perception_eval is not None:
            pivot = t.perception_eval.pivot_table(index="part", columns="metric",
                                                  values="value", aggfunc="first").reset_index()
            sec.add_table(f"{name}: accuracy and speed", pivot)
        if t.perception_timings is not None:
            sec.add_table(f"{name}: timings", t.perception_timings)
    if not sec.tables:
        sec.missing = "no perception/eval.parquet found (perception stages did not run)"
    return sec


def _footage_summary(t) -> pd.DataFrame:
    """One row per footage measure: detection rates and jitter (perception), who was taken
    (persons), the fit's reprojection error and the avatar's held-out scores, at 256 px."""
    q = t.footage_quality
    rows = [(f"{r.metric} ({r.part})", r.value, int(r.count)) for r in q.itertuples()]
    height = read_rgb(t.footage_overlays[0]).shape[0] if t.footage_overlays else None
    if t.persons is not None and len(t.persons):
        p = t.persons
        per_frame = p.groupby(["view", "frame"]).size()
        rows.append(("people per frame (mean)", float(per_frame.mean()), len(per_frame)))
        for how, n in p[p["chosen"]]["chosen_by"].value_counts().items():
            rows.append((f"signer taken by: {how}", float(n), int(n)))
    if t.fit_eval is not None and height:
        fe = t.fit_eval[t.fit_eval["metric"] == "reprojection"]
        for r in fe.itertuples():
            rows.append((f"fit reprojection error ({r.part}), px at 256 px height",
                         float(r.value) * 256.0 / height, 0))
    for variant, m in t.avatar_metrics.items():
        sel = m[(m["split"] == "novel_pose") & (m["part"] == "full")]
        if "protocol" in sel:
            sel = sel[sel["protocol"] == "mask_only"]
        if "refine" in sel:
            sel = sel[~sel["refine"].astype(bool)]
        for r in sel.itertuples():
            rows.append((f"avatar {variant}: held-out {r.metric} (masked)", float(r.value),
                         int(getattr(r, "n_images", 0) or 0)))
        if len(sel):
            rows.append((f"avatar {variant}: training seconds", float(sel["train_seconds"].iloc[0]),
                         0))
    return pd.DataFrame(rows, columns=["measure", "value", "count"])


def footage_section(res: Results, assets: Assets) -> Section:
    """Footage sequences (those with perception/quality.parquet); the report has this section
    only when a run holds footage."""
    sec = Section("footage", "2b. Real footage (no ground truth)",
                  "What can be measured without ground truth (signsplat.perception.quality): "
                  "the share of frames in which each part is found (a hand: among the frames "
                  "in which the pose shows it in view), keypoint jitter (median second "
                  "difference, px at a 256-pixel frame height), who the person detector saw "
                  "and how the signer was taken, the fit's reprojection error and the "
                  "avatar's held-out scores (every 10th frame, masked by the perception "
                  "masks). Overlays: the person mask (green) and the keypoints (body red, face "
                  "yellow, left hand blue, right hand magenta); the fit's overlays are in "
                  "section 3.")
    for name, t in res.scenes.items():
        if t.footage_quality is None:
            continue
        sec.add_table(f"{name}: footage measures", _footage_summary(t))
        secs = bench_seconds(res.benchmarks, "perception_quality", name)
        seg = bench_seconds(res.benchmarks, "segment", name)
        kps = bench_seconds(res.benchmarks, "detect_keypoints", name)
        total = sum(s for s in (secs, seg, kps) if s is not None) or None
        if t.persons is not None and len(t.persons):
            path = plots.signer_track(t.persons, assets.path(f"{name}_signer_track"), name)
            sec.figures.append(Figure(assets.rel(path), f"{name}: who was taken as the signer "
                                      "(mid-hip x of every detected person, grey; the signer's "
                                      "by how they were taken); a jump of the line onto "
                                      "another track is a change of person", seg, "segment"))
        for img in t.footage_overlays:
            sec.figures.append(Figure(assets.copy(img), f"{name}: frame {img.stem}", total,
                                      "segment + detect_keypoints + perception_quality "
                                      "(whole sequence)"))
    return sec


def fit_section(res: Results, assets: Assets) -> Section:
    sec = Section("fit", "3. SMPL-X fitting errors",
                  "MPJPE / PA-MPJPE per part, reprojection and camera errors, and image_error: "
                  "how many pixels the fitted body lands from the true one in the images (what "
                  "an avatar trained on the fit inherits); overlays show the fitted mesh and "
                  "skeleton on the input images (the detections as white crosses) and the "
                  "person mask's outline (magenta) beside the fitted body's (cyan).")
    for name, t in res.scenes.items():
        if t.fit_eval is None:
            continue
        fe = t.fit_eval
        secs = float(fe["seconds_total"].iloc[0]) if len(fe) else None
        cols = [c for c in ("mode", "keypoints", "metric", "part", "value", "unit") if c in fe]
        offsets = fe.attrs.get("keypoint_offsets", "none")
        whose = "" if offsets == "none" else \
            f"; fitted to the detector's own keypoints, {Path(offsets).name}"
        legs = fe.attrs.get("legs_held", "none")
        if legs != "none":
            whose += f"; legs no view sees ({legs}) kept at the rest pose"
        sec.add_table(f"{name}: fit accuracy (fit took {_fmt_seconds(secs)}{whose})", fe[cols])
        bench = bench_seconds(res.benchmarks, "fit_smplx", name)
        for img in t.fit_overlays:
            sec.figures.append(Figure(assets.copy(img), f"{name}: {img.stem}",
                                      bench if bench is not None else secs,
                                      "fit_smplx (whole sequence)"))
    if not sec.tables:
        sec.missing = "no fit/fit_eval.parquet found (fitting did not run)"
    return sec


def colmap_section(res: Results) -> Section:
    sec = Section("colmap", "4. COLMAP versus the SMPL-X camera solve")
    keep = ["method", "setting", "frame", "images", "registered", "points3d", "reproj_error_px",
            "rot_error_deg", "centre_error_m", "focal_error_pct", "seconds", "cpu_seconds",
            "status"]
    for name, t in res.scenes.items():
        if t.colmap is not None:
            sec.add_table(name, t.colmap[[c for c in keep if c in t.colmap]])
    if not sec.tables:
        sec.missing = "no colmap/colmap_compare.parquet found (multi-view scenes only)"
    return sec


def _avatar_summary(m: pd.DataFrame) -> pd.DataFrame:
    """PSNR/SSIM/LPIPS per split and part, background replaced (the paper's protocol); with
    test-time refinement in columns of their own ("psnr refined", ...) where it was run. The
    PSNR's standard error over the images follows it ("psnr ±") where the table has one."""
    d = m
    if "protocol" in d:
        d = d[d["protocol"] == "bg_replaced"]
    refine = d["refine"].astype(bool) if "refine" in d else pd.Series(False, index=d.index)

    def table(rows: pd.DataFrame) -> pd.DataFrame:
        out = rows.pivot_table(index=["split", "part"], columns="metric", values="value",
                               aggfunc="mean")
        if "std_error" in rows and "psnr" in out:
            err = rows[rows["metric"] == "psnr"].groupby(["split", "part"])["std_error"].mean()
            out.insert(list(out.columns).index("psnr") + 1, "psnr ±", err)
        return out

    out = table(d[~refine])
    if refine.any():
        out = out.join(table(d[refine]).add_suffix(" refined"), how="left")
    out = out.reset_index()
    out.columns.name = None
    return out


def _avatar_protocol(m: pd.DataFrame) -> str:
    """The evaluation protocol the metrics table states: background, split rule, held-out pose."""
    if not len(m):
        return ""
    first = m.iloc[0]
    parts = []
    if "background" in first:
        parts.append(f"background replaced by rgb({first['background']})")
    if "split_rule" in first:
        parts.append(str(first["split_rule"]))
    if "heldout_pose" in first:
        parts.append("held-out frames posed by the fit" if first["heldout_pose"] == "fit" else
                     "held-out frames posed by the fit plus the training frames' fine-tuning "
                     "interpolated from their neighbours (no test image used)")
    if "smplx_source" in first:
        parts.append(f"SMPL-X: {first['smplx_source']}")
    return "; ".join(parts)


def _views_summary(v: pd.DataFrame) -> pd.DataFrame:
    """PSNR (dB) per split and refinement (rows) and camera (columns)."""
    out = v.pivot_table(index=["split", "refine"], columns="view", values="psnr",
                        aggfunc="mean")
    out.columns = [f"view {c}" for c in out.columns]
    return out.reset_index()


def _weak_views_note(v: pd.DataFrame) -> str:
    weak = weak_views(v[~v["refine"].astype(bool)])
    if not len(weak):
        return f"(no camera more than {WEAK_VIEW_DB:g} dB below the median of the others)"
    names = ", ".join(f"view {int(r.view)} on {r.split} ({r.below_median_db:.1f} dB below)"
                      for r in weak.itertuples())
    return f"- far below the other cameras: {names}; check that camera"


CLOSEUP_PARTS = {"left_hand": (J.KP_LEFT_HAND, 0.18), "right_hand": (J.KP_RIGHT_HAND, 0.18),
                 "face": (J.KP_FACE, 0.25)}
_PANEL = re.compile(r"f(\d+)_v(\d+)")


def closeups(panel_path: Path, kp: pd.DataFrame, cams: pd.DataFrame | None,
             out: dict[str, Path]) -> dict[str, Path]:
    """Crop hands and face out of a (ground truth | render | error) panel, the three crops side
    by side. Crop centres are the mean of the part's 2D keypoints in that view and frame
    (rescaled from the camera's native size to the panel's). Returns part -> written path."""
    m = _PANEL.search(panel_path.stem)
    if m is None or kp is None:
        return {}
    frame, view = int(m.group(1)), int(m.group(2))
    sel = kp[(kp["frame"] == frame) & (kp["view"] == view)]
    if not len(sel):
        return {}
    panel = read_rgb(panel_path)
    h, w3 = panel.shape[:2]
    w = w3 // 3
    native_w, native_h = w, h
    if cams is not None and len(cams):
        c = cams[cams["view"] == view]
        if len(c):
            native_w, native_h = int(c["width"].iloc[0]), int(c["height"].iloc[0])
    sx, sy = w / native_w, h / native_h
    written = {}
    for part, (idx, frac) in CLOSEUP_PARTS.items():
        p = sel[sel["kp"].isin(idx)]
        if "score" in p:
            p = p[p["score"] > 0]
        p = p[np.isfinite(p["x"]) & np.isfinite(p["y"])]
        if not len(p):
            continue
        cx, cy = float(p["x"].mean()) * sx, float(p["y"].mean()) * sy
        half = max(4, int(round(frac * max(w, h) / 2)))
        x0 = int(np.clip(round(cx) - half, 0, max(0, w - 2 * half)))
        y0 = int(np.clip(round(cy) - half, 0, max(0, h - 2 * half)))
        tiles = [panel[y0:y0 + 2 * half, k * w + x0:k * w + x0 + 2 * half] for k in range(3)]
        if min(t.size for t in tiles) == 0:
            continue
        written[part] = write_png(out[part], np.concatenate(tiles, 1))
    return written


STUDY_PREFIXES = ("abl_", "sw_")


def is_study_variant(variant: str) -> bool:
    """Ablation and sweep variants (shown in their own sections, not one by one)."""
    return variant.startswith(STUDY_PREFIXES)


def avatar_section(res: Results, assets: Assets) -> Section:
    sec = Section("avatar", "5. Avatar metrics per part",
                  "Held-out frames (novel pose) and cameras (novel view); protocol "
                  "'bg_replaced' (the paper's), without test-time refinement and, in the "
                  "'refined' columns, after refining each held-out frame's pose on its own "
                  "images (the figure without is the stricter one). Images: "
                  "ground truth | render | error map (inferno, x4). Close-ups crop hands and "
                  "face around their 2D keypoints. Ablation (abl_*) and sweep (sw_*) variants "
                  "are summarised in sections 6 and 7.")
    for name, t in res.scenes.items():
        kp = pd.read_parquet(t.keypoints_2d, columns=["view", "frame", "kp", "x", "y", "score"]) \
            if t.keypoints_2d is not None and t.avatar_images else None
        for variant, m in t.avatar_metrics.items():
            if is_study_variant(variant):
                continue
            train_s = bench_seconds(res.benchmarks, f"train_avatar_{variant}", name)
            eval_s = bench_seconds(res.benchmarks, f"evaluate_{variant}", name)
            if train_s is None and "train_seconds" in m and len(m):
                train_s = float(m["train_seconds"].iloc[0])
            protocol = _avatar_protocol(m)
            sec.add_table(f"{name} / {variant}: training {_fmt_seconds(train_s)}, "
                          f"evaluation {_fmt_seconds(eval_s)}"
                          + (f" ({protocol})" if protocol else ""), _avatar_summary(m))
            views = t.avatar_views.get(variant)
            if views is not None and views["view"].nunique() > 1:
                sec.add_table(f"{name} / {variant}: whole-image PSNR per camera "
                              f"{_weak_views_note(views)}", _views_summary(views))
            for img in t.avatar_images.get(variant, []):
                sec.figures.append(Figure(assets.copy(img), f"{name} / {variant}: {img.stem} "
                                          "(ground truth | render | error)", train_s,
                                          "train_avatar"))
                key = f"{name}_{variant}_{img.stem}"
                crops = closeups(img, kp, t.cameras,
                                 {p: assets.path(f"{key}_{p}") for p in CLOSEUP_PARTS})
                for part, path in crops.items():
                    sec.figures.append(Figure(assets.rel(path), f"{name} / {variant}: "
                                              f"{img.stem} {part} close-up", train_s,
                                              "train_avatar", pixelated=True))
        logs = {v: df for v, df in t.train_logs.items() if not is_study_variant(v)}
        if logs:
            path = plots.training_curves(logs, assets.path(f"{name}_training_curves"))
            total = sum(float(df["seconds"].max()) for df in logs.values()
                        if "seconds" in df and len(df))
            sec.figures.append(Figure(assets.rel(path), f"{name}: training PSNR against "
                                      "seconds, per variant", total,
                                      "training seconds, all variants"))
    if not sec.tables:
        sec.missing = "no eval/{variant}/metrics.parquet found (the avatar was not evaluated)"
    return sec


def ablation_section(res: Results, assets: Assets) -> Section:
    sec = Section("ablations", "6. Ablations (paper Table 5)",
                  "Same scene, frames, held-out cameras and seed for every variant; the full "
                  "model is the demo profile plus the config's ablations.base with every switch "
                  "on (the demo itself leaves regularisation off), and each other row turns one "
                  "switch off; every row is trained at each budget of ablations.iterations. "
                  "Splits: novel_pose (held-out frames, training cameras), novel_view (training "
                  "frames, held-out cameras: the paper's claim for the regulariser is made "
                  "here), novel_pose_view (both). Background replaced, no test-time "
                  "refinement; training seconds from the Snakemake benchmark files.")
    for name, t in res.scenes.items():
        if t.ablations is None or not len(t.ablations):
            continue
        a = t.ablations
        if "split" not in a:  # a table of the single-split study
            a = a.assign(split="novel_pose", iterations=0)
        win = runs.winners(a)
        sec.add_table(f"{name}: per budget and split, the best variant and the full model's "
                      "margin over the best other (negative: beaten). "
                      f"{runs.ssim_finding(a)}", win)
        sec.add_table(f"{name}: every variant, budget and split", a)
        for (iters, split), g in a.groupby(["iterations", "split"]):
            if g["ssim"].notna().any():
                path = plots.bars(g.set_index("variant")["ssim"],
                                  assets.path(f"{name}_ablation_{iters}_{split}"),
                                  f"SSIM ({split}, full image)")
                sec.figures.append(Figure(assets.rel(path), f"{name}: SSIM per ablation, "
                                          f"{split}, {iters} steps",
                                          float(g.drop_duplicates("avatar_variant")[
                                              "train_seconds"].sum()),
                                          "training seconds of these variants"))
        logs = {v: t.train_logs[v] for v in a.get("avatar_variant", []) if v in t.train_logs}
        if logs:
            total = float(a.drop_duplicates("avatar_variant")["train_seconds"].sum())
            path = plots.training_curves(logs, assets.path(f"{name}_ablation_curves"))
            sec.figures.append(Figure(assets.rel(path), f"{name}: training PSNR of the "
                                      "ablation variants", total,
                                      "training seconds, all ablation variants"))
        r = t.regularizer
        if r is not None and len(r):
            sec.add_table(f"{name}: the regulariser's weights scaled (0 = off) on the full "
                          "model", r)
            path = plots.regularizer_tradeoff(r, assets.path(f"{name}_regularizer"), name)
            sec.figures.append(Figure(assets.rel(path), f"{name}: how the regulariser's weight "
                                      "trades novel-pose against novel-view PSNR",
                                      float(r.drop_duplicates("avatar_variant")[
                                          "train_seconds"].sum()),
                                      "training seconds of the sweep's variants"))
    if not sec.tables:
        sec.missing = "no {scene}/ablations.parquet found (run `snakemake ablations`)"
    return sec


def sweep_section(res: Results, assets: Assets, demo: str,
                  fronts: str | Path | None = None) -> Section:
    """The sweep of each sequence that ran it; with ``fronts`` (an ``avatar_fronts`` table,
    benchmarks/bench_avatar_fronts.py) also the front before and after a change."""
    sec = Section("sweep", "7. Accuracy versus time",
                  "Each point is one setting (iterations, training resolution or point budget "
                  "changed from the sweep centre); x: training wall-clock seconds from the "
                  "Snakemake benchmark files; y: novel-pose PSNR / SSIM evaluated at the native "
                  "image size. Red: the Pareto front (no other setting is both faster and at "
                  "least as good). Star: the `make demo` configuration.")
    if fronts is not None and Path(fronts).exists():
        f = pd.read_parquet(fronts)
        path = plots.avatar_fronts(f, assets.path("avatar_fronts"))
        codes = ", ".join(f"{c} = {g['commit'].iloc[0]}" for c, g in f.groupby("code", sort=False))
        sec.figures.append(Figure(assets.rel(path), "The sweep's settings (ground-truth SMPL-X) "
                                  f"trained by two versions of the code ({codes}), one after "
                                  f"the other on one machine on {', '.join(f['measured'].unique())}"
                                  " (benchmarks/bench_avatar_fronts.py)",
                                  float(f["seconds"].sum()), "training seconds, both codes"))
        sec.add_table("the front before and after (benchmark)", f)
    for name, t in res.scenes.items():
        if t.sweep is None or not len(t.sweep):
            continue
        s = t.sweep.copy()
        s["pareto_psnr"] = plots.pareto_front(s["seconds"], s["psnr"])
        if "ssim" in s:
            s["pareto_ssim"] = plots.pareto_front(s["seconds"], s["ssim"])
        path = plots.accuracy_vs_time(s, assets.path(f"{name}_sweep"), label="setting",
                                      highlight=demo, title=name)
        sec.figures.append(Figure(assets.rel(path), f"{name}: PSNR/SSIM against seconds",
                                  float(s["seconds"].sum()),
                                  "training seconds, all sweep settings together"))
        sec.add_table(name, s)
    if not sec.tables:
        sec.missing = "no {scene}/sweep.parquet found (run `snakemake sweep`)"
    return sec


def _video_frames(video: Path, n: int, out_key: str, assets: Assets) -> list[Path]:
    from signsplat.io.video import iter_frames

    frames = [f for _, f in iter_frames(video)]
    picks = np.linspace(0, len(frames) - 1, num=min(n, len(frames))).round().astype(int) \
        if frames else []
    return [write_png(assets.path(f"{out_key}_{i:04d}"), frames[i]) for i in picks]


def stitch_section(res: Results, assets: Assets) -> Section:
    sec = Section("stitch", "8. Stitched video",
                  "English sentences signed by the trained avatar (glosses stitched by SLERP of "
                  "the joint rotations), beside the 2D keypoint baseline; frames evenly spaced "
                  "over each video. The gloss plan written beside each video is shown with it.")
    for path, df in res.stitch_tables:
        sec.add_table(str(path.relative_to(res.root)), df)
    secs = None
    sel = res.benchmarks[res.benchmarks["job"].str.startswith("stitch")]
    if len(sel):
        secs = float(sel["seconds"].sum())
    avatar = [v for v in res.stitch_videos if not v.name.endswith(".baseline2d.mp4")]
    for video in avatar[:3]:
        plan = video.with_name(video.name[:-len(".mp4")] + ".plan.txt")
        if plan.is_file():
            sec.tables.append((f"{video.name}: gloss plan",
                               f"<pre>{escape(plan.read_text(encoding='utf-8'))}</pre>"))
        shown = [(video, "avatar")]
        base = video.with_name(video.name[:-len(".mp4")] + ".baseline2d.mp4")
        if base.is_file():
            shown.append((base, "2D baseline"))
        for v, kind in shown:
            for f in _video_frames(v, 4, v.stem, assets):
                sec.figures.append(Figure(assets.rel(f), f"{v.name} ({kind}): frame "
                                          f"{f.stem[-4:]}", secs, "stitch rules (benchmark)"))
    if not sec.tables and not sec.figures:
        sec.missing = "no stitched video or stitch_eval.parquet found (stitching did not run)"
    return sec


def runtime_section(res: Results, assets: Assets,
                    benchmark_patterns: dict | None = None) -> Section:
    sec = Section("runtimes", "9. Run time per rule",
                  "Snakemake `benchmark:` files (wall-clock and CPU seconds, peak memory); for a "
                  "run on SLURM, the scheduler's own figures (sacct) beside them.")
    b = res.benchmarks
    if not len(b):
        sec.missing = "no benchmark files in results/_benchmarks"
        return sec
    path = plots.rule_times(b, assets.path("rule_times"))
    sec.figures.append(Figure(assets.rel(path), "seconds per job (longest 30)",
                              float(b["seconds"].sum()), "sum over all jobs"))
    sec.add_table("Jobs", b.drop(columns=["file"]).sort_values(
        "seconds", ascending=False))
    for caption, df in accounting.cost_tables(res.root, benchmark_patterns):
        sec.add_table(caption, df)
    return sec


# --- page -------------------------------------------------------------------------------------

TEMPLATE = jinja2.Template("""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8">
<title>{{ title|e }}</title>
<style>
body{font-family:system-ui,sans-serif;margin:1.5em auto;max-width:1200px;color:#222}
h2{border-bottom:1px solid #ccc;padding-bottom:.2em;margin-top:2em}
table.data{border-collapse:collapse;font-size:.85em;margin:.5em 0 1em}
table.data th,table.data td{border:1px solid #ddd;padding:2px 6px;text-align:right}
table.data th{background:#f3f3f3}
.figs{display:flex;flex-wrap:wrap;gap:12px}
figure{margin:0;max-width:100%}
figure img{max-width:100%;border:1px solid #ddd}
figure img.px{image-rendering:pixelated;width:360px}
figcaption{font-size:.8em;color:#444}
.secs{font-weight:bold;color:#0a5}
.missing{color:#a60;font-style:italic}
nav a{margin-right:1em}
</style></head><body>
<h1>{{ title|e }}</h1>
<p>Results folder: <code>{{ root|e }}</code>. Sequences: {{ scenes|join(', ')|e or 'none' }}.</p>
<nav>{% for s in sections %}<a href="#{{ s.id }}">{{ s.title|e }}</a>{% endfor %}</nav>
{% for s in sections %}
<section id="{{ s.id }}"><h2>{{ s.title|e }}</h2>
{% if s.intro %}<p>{{ s.intro|e }}</p>{% endif %}
{% if s.missing %}<p class="missing">Not available: {{ s.missing|e }}.</p>{% endif %}
{% for cap, tab in s.tables %}<h3>{{ cap|e }}</h3>{{ tab|safe }}{% endfor %}
{% if s.figures %}<div class="figs">{% for f in s.figures %}
<figure><img src="{{ f.src|e }}" alt="{{ f.caption|e }}"{% if f.pixelated %} class="px"{% endif %}>
<figcaption>{{ f.caption|e }} · <span class="secs">{{ fmt(f.seconds) }}</span>
({{ f.seconds_note|e }})</figcaption></figure>{% endfor %}</div>{% endif %}
</section>
{% endfor %}
</body></html>
""")


def build_sections(res: Results, report_dir: Path, demo: str = "demo",
                   benchmark_patterns: dict | None = None,
                   fit_suite: str | Path | None = None,
                   avatar_fronts: str | Path | None = None) -> list[Section]:
    """The report's sections; with ``fit_suite`` (a ``fit_suite`` table that exists, written
    by benchmarks/fit_suite.py) also the suite's section, its figure taken from beside it;
    with ``avatar_fronts`` (benchmarks/bench_avatar_fronts.py) the front before and after a
    change in the accuracy-versus-time section."""
    assets = Assets(report_dir)
    footage = [footage_section(res, assets)] if any(
        t.footage_quality is not None for t in res.scenes.values()) else []
    fit_sweep = fit_sweep_section({n: t.fit_sweep for n, t in res.scenes.items()}, assets)
    sections = [scene_section(res, assets), perception_section(res), *footage,
                fit_section(res, assets), *([fit_sweep] if fit_sweep is not None else []),
                colmap_section(res), avatar_section(res, assets), ablation_section(res, assets),
                sweep_section(res, assets, demo, avatar_fronts), stitch_section(res, assets),
                runtime_section(res, assets, benchmark_patterns)]
    if fit_suite is not None:
        suite = fit_suite_section(fit_suite, assets, Path(fit_suite).with_suffix(".svg"))
        if suite is not None:
            sections.append(suite)
    return sections


def write_tables(sections: list[Section], folder: Path) -> list[Path]:
    """Every table of the report as ``{section}_{n:02d}_{caption}.tsv`` in ``folder`` (what
    ``snakemake --report`` shows as tables); files of an earlier report are replaced."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    for old in folder.glob("*.tsv"):
        old.unlink()
    written = []
    for sec in sections:
        for n, (caption, df) in enumerate(sec.frames):
            # the caption up to its first ':' (sequence / variant), not its changing figures
            slug = re.sub(r"[^A-Za-z0-9]+", "_", caption.split(":")[0]).strip("_")[:60]
            path = folder / f"{sec.id}_{n:02d}_{slug}.tsv"
            with atomic_path(path) as tmp:
                df.to_csv(tmp, sep="\t", index=False)
            written.append(path)
    return written


def write_report(results: str | Path, out: str | Path, repo_scenes: str | Path | None = None,
                 demo: str = "demo", title: str = "SignSplat report",
                 tables_dir: str | Path | None = None,
                 benchmark_patterns: dict | None = None,
                 fit_suite: str | Path | None = None,
                 avatar_fronts: str | Path | None = None) -> Path:
    """Collect ``results`` and write the report to ``out`` (assets in ``out``'s folder); with
    ``tables_dir``, every table also as a TSV file there. ``benchmark_patterns`` (rule ->
    its benchmark and log file patterns) names each job's rule in the cost tables; with
    ``fit_suite`` (the suite benchmark's table, when it exists) a section for the fit's
    generalisation suite; with ``avatar_fronts`` the avatar's front before and after a change."""
    out = Path(out)
    res = collect(results, repo_scenes)
    sections = build_sections(res, out.parent, demo, benchmark_patterns, fit_suite,
                              avatar_fronts)
    if tables_dir is not None:
        write_tables(sections, Path(tables_dir))
    page = TEMPLATE.render(title=title, root=str(Path(results).resolve()),
                           scenes=list(res.scenes), sections=sections, fmt=_fmt_seconds)
    with atomic_path(out) as tmp:
        tmp.write_text(page, encoding="utf-8")
    return out


__all__ = ["write_report", "build_sections", "closeups", "table_html", "Figure", "Section"]
