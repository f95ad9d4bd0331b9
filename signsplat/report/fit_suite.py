"""The multi-view fit's generalisation suite (issue 29): one row per scene, a summary against the
targets, a figure, and a report section when the suite has run.

Rows come from a suite results folder (``benchmarks/fit_suite.py`` runs the workflow into it):
``{scene}/fit/fit_eval.parquet`` and ``fit_log.json``, the scene spec, and the Snakemake
benchmark files (seconds of simulate, segment, detect_keypoints and fit_smplx). A scene whose
fit did not finish gets a row with ``status`` saying so (a crash is a result too).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd

from signsplat.io.tables import Table, register_table

#: the targets of issue 29 for scenes with 3 or more cameras
TARGETS = {"camera_rotation_deg": 1.0, "camera_centre_m": 0.02, "body_mpjpe_mm": 25.0}

FIT_SUITE = register_table(Table(
    "fit_suite",
    "The multi-view fit on the generalisation suite (config/scenes/suite), one row per scene.",
    {
        "scene": "str suite scene name",
        "cameras": "int32 number of cameras",
        "arc_deg": "float64 azimuth span of the cameras (degrees; 360 for a ring)",
        "distance_m": "float64 mean horizontal camera distance (m)",
        "image": "str width x height (px)",
        "frames": "int32 frames fitted",
        "effects": "str effects the scene declares (comma-separated)",
        "keypoints": "str detected or ground_truth",
        "camera_rotation_deg": "float64 mean camera rotation error after the gauge alignment",
        "camera_rotation_max_deg": "float64 largest camera rotation error",
        "camera_centre_m": "float64 mean camera centre error (m, similarity-aligned)",
        "camera_centre_max_m": "float64 largest camera centre error (m)",
        "body_mpjpe_mm": "float64 body MPJPE (mm) in the ground-truth frame",
        "body_pa_mpjpe_mm": "float64 body PA-MPJPE (mm)",
        "body_seen_mpjpe_mm": "float64 body MPJPE (mm) over the joints at least two cameras "
                              "see in their images (fit_eval part body_seen)",
        "hands_mpjpe_mm": "float64 hands MPJPE (mm, wrist-rooted)",
        "hands_pa_mpjpe_mm": "float64 hands PA-MPJPE (mm)",
        "body_jitter": "float64 body acceleration error (mm/frame^2)",
        "hands_jitter": "float64 hands acceleration error (mm/frame^2)",
        "image_error_px": "float64 mean px between the fitted and the true body in the images",
        "camera_init": "str the winning initial hypothesis (sfm, pnp, pnp_ransac, prior)",
        "camera_status": "str each view's camera source (comma-separated; unplaced views named)",
        "unplaced": "int32 views the initialisation could not place",
        "doubtful": "int32 views left where they were placed although the other side of the "
                    "signer fits their detections a little better (a warning in the fit log; "
                    "fit_log.json camera_init_doubtful)",
        "mask_turned": "int32 doubtful views that the person masks turned around after the "
                       "keypoint stages, the fit then starting again (fit_log.json "
                       "camera_mask_sides)",
        "mask_kept": "int32 doubtful views whose person masks kept them where they were "
                     "placed (fit_log.json camera_mask_sides)",
        "cameras_held": "int32 views whose cameras a stage held because their keypoints agreed "
                        "with the other views' (a stage's hold_cameras_within_px; the most of "
                        "any stage, fit_log.json cameras_held; fixed cameras such as the "
                        "reference are never counted)",
        "fit_seconds": "float64 wall-clock seconds of the fit rule (Snakemake benchmark)",
        "pipeline_seconds": "float64 simulate + perception + fit seconds",
        "status": "str ok, or what failed",
        "meets_target": "bool cameras <= 1 deg and <= 2 cm, body MPJPE <= 25 mm, no unplaced "
                        "view (scenes with 3 or more cameras; False for the others)",
    },
))

_METRICS = {  # fit_eval (metric, part) -> column
    ("camera_rotation", "cameras"): "camera_rotation_deg",
    ("camera_rotation_max", "cameras"): "camera_rotation_max_deg",
    ("camera_centre", "cameras"): "camera_centre_m",
    ("camera_centre_max", "cameras"): "camera_centre_max_m",
    ("mpjpe", "body"): "body_mpjpe_mm",
    ("pa_mpjpe", "body"): "body_pa_mpjpe_mm",
    ("mpjpe", "body_seen"): "body_seen_mpjpe_mm",
    ("mpjpe", "hands"): "hands_mpjpe_mm",
    ("pa_mpjpe", "hands"): "hands_pa_mpjpe_mm",
    ("jitter", "body"): "body_jitter",
    ("jitter", "hands"): "hands_jitter",
    ("image_error", "all"): "image_error_px",
}


def fit_errors(ev: pd.DataFrame) -> dict[str, float]:
    """The error columns of a fit's ``fit_eval`` table (NaN where it has no such row)."""
    out = {}
    for (m, p), col in _METRICS.items():
        sel = ev[(ev["metric"] == m) & (ev["part"] == p)]["value"]
        out[col] = float(sel.iloc[0]) if len(sel) else float("nan")
    return out


def _rig_summary(spec: dict) -> dict:
    cams = spec["cameras"]
    if cams.get("views"):
        az = np.array([v["azimuth_degrees"] for v in cams["views"]], float)
        dist = np.array([v.get("distance", cams.get("distance", 2.0)) for v in cams["views"]])
    else:
        n = int(cams.get("count", 6))
        arc = 360.0 if cams.get("layout") == "ring" else float(cams.get("arc_degrees", 150))
        az = np.linspace(-arc / 2, arc / 2, n)
        dist = np.full(n, float(cams.get("distance", 2.0)))
    srt = np.sort(np.mod(az, 360.0))
    gaps = np.diff(np.r_[srt, srt[0] + 360.0])
    span = 360.0 - float(gaps.max()) if len(az) > 1 else 0.0
    effects = [e if isinstance(e, str) else next(iter(e)) for e in spec.get("effects", [])]
    return {"cameras": len(az), "arc_deg": round(span, 1), "distance_m": float(dist.mean()),
            "image": f"{cams.get('width', 256)}x{cams.get('height_px', 256)}",
            "effects": ",".join(effects)}


def _bench(bench_dir: Path, scene: str, job: str) -> float:
    f = bench_dir / scene / f"{job}.tsv"
    try:
        return float(pd.read_csv(f, sep="\t")["s"].mean())
    except (OSError, KeyError, ValueError, pd.errors.EmptyDataError):
        return float("nan")


def scene_row(results: str | Path, scene: str, spec: dict, keypoints: str = "detected") -> dict:
    """The suite row of one scene from its results (``status`` says what is missing)."""
    root = Path(results)
    row: dict = {"scene": scene, **_rig_summary(spec), "frames": int(spec.get("max_frames") or 0),
                 "keypoints": keypoints}
    row.update({c: float("nan") for c in _METRICS.values()})
    row.update({"camera_init": "", "camera_status": "", "unplaced": 0, "doubtful": 0,
                "mask_turned": 0, "mask_kept": 0, "cameras_held": 0})
    fit_dir = root / scene / "fit"
    bench = root / "_benchmarks"
    row["fit_seconds"] = _bench(bench, scene, "fit_smplx")
    parts = [_bench(bench, scene, j) for j in ("simulate", "segment", "detect_keypoints")]
    row["pipeline_seconds"] = float(np.nansum(parts + [row["fit_seconds"]]))
    ev_path, log_path = fit_dir / "fit_eval.parquet", fit_dir / "fit_log.json"
    if not ev_path.exists() or not log_path.exists():
        log_file = root / "_logs" / scene / "fit_smplx.log"
        last = ""
        if log_file.exists():
            lines = [ln for ln in log_file.read_text(errors="replace").splitlines() if ln]
            last = lines[-1][-200:] if lines else ""
        row["status"] = f"no fit output{': ' + last if last else ''}"
        row["meets_target"] = False
        return row
    row.update(fit_errors(pd.read_parquet(ev_path)))
    summary = json.loads(log_path.read_text())
    status = list(summary.get("camera_status", []))
    row["camera_init"] = str(summary.get("log", {}).get("camera_init", ""))
    row["camera_status"] = ",".join(status)
    row["unplaced"] = int(sum(s == "unplaced" for s in status))
    row["doubtful"] = int(summary.get("log", {}).get("camera_init_doubtful", 0))
    sides = summary.get("log", {}).get("camera_mask_sides", {})
    row["mask_turned"] = int(sum(bool(s.get("turned")) for s in sides.values()))
    row["mask_kept"] = len(sides) - row["mask_turned"]
    held = summary.get("log", {}).get("cameras_held", {})
    row["cameras_held"] = max((len(v) for v in held.values()), default=0)
    row["frames"] = int(sum(summary.get("provenance", {}).values()) or row["frames"])
    finite = np.isfinite([row[c] for c in ("camera_rotation_deg", "camera_centre_m",
                                           "body_mpjpe_mm")]).all()
    row["status"] = "ok" if finite else "non-finite figures"
    row["meets_target"] = bool(row["cameras"] >= 3 and finite and row["unplaced"] == 0 and all(
        row[k] <= v for k, v in TARGETS.items()))
    return row


def suite_table(rows: list[dict]) -> pd.DataFrame:
    """Rows -> the ``fit_suite`` table (columns in the documented order and types)."""
    df = pd.DataFrame(rows, columns=list(FIT_SUITE.columns))
    for c in ("cameras", "frames", "unplaced", "doubtful", "mask_turned", "mask_kept",
              "cameras_held"):
        df[c] = df[c].astype(np.int32)
    df["meets_target"] = df["meets_target"].astype(bool)
    return df


def summarise(df: pd.DataFrame) -> dict:
    """The issue's Done-when figures of a suite table: share of the scenes with 3 or more
    cameras meeting the targets, failures, and the two-camera scenes' figures."""
    multi = df[df["cameras"] >= 3]
    two = df[df["cameras"] < 3]
    ok = df["status"] == "ok"
    return {
        "scenes": int(len(df)),
        "multi_camera_scenes": int(len(multi)),
        "meeting_targets": int(multi["meets_target"].sum()),
        "share_meeting_targets": float(multi["meets_target"].mean()) if len(multi) else
        float("nan"),
        "failed_or_nan": int((~ok).sum()),
        "unplaced_views": int(df["unplaced"].sum()),
        "two_camera": two[["scene", "camera_rotation_deg", "camera_centre_m",
                           "body_mpjpe_mm"]].to_dict("records"),
        "median_camera_rotation_deg": float(multi["camera_rotation_deg"].median()),
        "median_body_mpjpe_mm": float(multi["body_mpjpe_mm"].median()),
        # the body target over the joints the cameras see (None: a table without the column)
        "body_seen_within_target": int((multi["body_seen_mpjpe_mm"] <=
                                        TARGETS["body_mpjpe_mm"]).sum())
        if "body_seen_mpjpe_mm" in multi else None,
        "pipeline_hours": float(df["pipeline_seconds"].sum() / 3600),
    }


def plot_suite(df: pd.DataFrame, path: str | Path) -> Path:
    """Per scene: camera rotation error, centre error and body MPJPE (log scale; a tick for
    the MPJPE over the joints the cameras see) with the targets as lines; scenes with 2
    cameras in grey (no target). SVG or PNG by suffix."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from signsplat.io.atomic import atomic_path

    path = Path(path)
    d = df.sort_values(["cameras", "scene"]).reset_index(drop=True)
    x = np.arange(len(d))
    colors = np.where(d["cameras"] < 3, "0.6",
                      np.where(d["meets_target"], "tab:green", "tab:red"))
    panels = (("camera_rotation_deg", "camera rotation (deg)", 1.0),
              ("camera_centre_m", "camera centre (m)", 0.02),
              ("body_mpjpe_mm", "body MPJPE (mm)", 25.0))
    fig, axes = plt.subplots(len(panels), 1, figsize=(max(6.0, 0.36 * len(d) + 2), 8),
                             sharex=True)
    for ax, (col, label, target) in zip(axes, panels):
        vals = d[col].to_numpy(float)
        shown = np.where(np.isfinite(vals), np.maximum(vals, 1e-3), np.nan)
        ax.bar(x, shown, color=colors)
        ax.axhline(target, color="k", lw=0.8, ls="--")
        ax.set_yscale("log")
        ax.set_ylabel(label)
        if col == "body_mpjpe_mm" and "body_seen_mpjpe_mm" in d:
            ax.plot(x, d["body_seen_mpjpe_mm"].to_numpy(float), "k_", ms=12,
                    label="over the joints two or more cameras see")
            ax.legend(fontsize=7, loc="upper left")
        for i in np.nonzero(~np.isfinite(vals))[0]:
            ax.text(x[i], target, "failed", rotation=90, ha="center", va="bottom", fontsize=7)
    axes[-1].set_xticks(x, [f"{s} ({c})" for s, c in zip(d["scene"], d["cameras"])],
                        rotation=70, ha="right", fontsize=8)
    axes[0].set_title("Multi-view fit on the suite: green meets the targets (dashed), red "
                      "misses, grey 2 cameras")
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format=path.suffix.lstrip(".") or "png", dpi=100, bbox_inches="tight")
    plt.close(fig)
    return path


def _camera_warnings(df: pd.DataFrame) -> str:
    note = ""
    bad = df[df["unplaced"] > 0]
    if len(bad):
        note += (" Warning: cameras that could not be placed (left out of the fit and of the "
                 "camera errors): " + ", ".join(f"{r.scene} ({r.unplaced})"
                                               for r in bad.itertuples()) + ".")
    doubt = df[df["doubtful"] > 0] if "doubtful" in df else df.iloc[:0]
    if len(doubt):
        note += (" Warning: cameras that may face the signer from the other side (their "
                 "detections fit there a little better; see the fit log and the overlays): "
                 + ", ".join(_doubt_told(r) for r in doubt.to_dict("records")) + ".")
    return note


def _doubt_told(row: dict) -> str:
    """``scene (n)``, and what the person masks decided of those views (tables written
    before the masks' check have no such columns)."""
    turned, kept = int(row.get("mask_turned", 0)), int(row.get("mask_kept", 0))
    masks = f"; by their person masks {turned} turned around, {kept} kept where placed" \
        if turned or kept else ""
    return f"{row['scene']} ({row['doubtful']}{masks})"


def fit_suite_section(parquet: str | Path, assets, figure: str | Path | None = None):
    """A report section (:class:`signsplat.report.html.Section`) for the suite table at
    ``parquet``, or None when the suite has not run. ``assets``: the report's
    :class:`~signsplat.report.html.Assets`; ``figure``: the suite's figure to copy beside it."""
    from signsplat.report.html import Figure, Section

    parquet = Path(parquet)
    if not parquet.exists():
        return None
    df = pd.read_parquet(parquet)
    s = summarise(df)
    sec = Section("fit_suite", "10. Multi-view fit on the generalisation suite (benchmark)",
                  f"{s['scenes']} scenes from config/scenes/suite (2-8 cameras, arcs up to "
                  f"360 degrees, 1.5-4 m, images down to 160 px, effects); "
                  f"{s['meeting_targets']} of {s['multi_camera_scenes']} scenes with 3 or more "
                  f"cameras meet cameras <= 1 deg and <= 2 cm and body MPJPE <= 25 mm; "
                  f"{s['failed_or_nan']} failed; {s['pipeline_hours']:.1f} h of pipeline."
                  + ("" if s["body_seen_within_target"] is None else
                     f" Over the body joints two or more cameras see, body MPJPE <= 25 mm on "
                     f"{s['body_seen_within_target']} of {s['multi_camera_scenes']}.")
                  + _camera_warnings(df))
    keep = ["scene", "cameras", "arc_deg", "distance_m", "image", "frames", "effects",
            "camera_rotation_deg", "camera_centre_m", "body_mpjpe_mm", "body_seen_mpjpe_mm",
            "hands_mpjpe_mm",
            "body_pa_mpjpe_mm", "hands_pa_mpjpe_mm", "body_jitter", "camera_init", "unplaced",
            "doubtful", "mask_turned", "mask_kept", "cameras_held", "fit_seconds", "status",
            "meets_target"]
    sec.add_table("per scene", df[[c for c in keep if c in df]])  # older tables lack some
    if figure is not None and Path(figure).exists():
        sec.figures.append(Figure(assets.copy(Path(figure)), "errors per scene",
                                  float(df["fit_seconds"].sum()), "fit seconds, all scenes"))
    return sec
