"""Figures of the report (matplotlib, Agg backend, PNG files). Each function takes plain data,
writes one PNG atomically and returns its path."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import matplotlib.ticker as mticker  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402

from signsplat.io.atomic import atomic_path  # noqa: E402


def nondominated(costs) -> np.ndarray:
    """Bool mask of the rows of ``costs`` (points x criteria, lower is better in each) that no
    other row dominates: no worse in every criterion and strictly better in one. Rows with a
    NaN are never on the front."""
    c = np.atleast_2d(np.asarray(costs, dtype=float))
    ok = np.isfinite(c).all(axis=1)
    front = np.zeros(len(c), dtype=bool)
    for i in np.flatnonzero(ok):
        better = ok & (c <= c[i]).all(axis=1) & (c < c[i]).any(axis=1)
        front[i] = not better.any()
    return front


def pareto_front(seconds, quality, lower_is_better: bool = False) -> np.ndarray:
    """Bool mask of the points no other point beats in (seconds, quality): another point
    dominates a point when it takes no more seconds, has no worse quality, and is strictly
    better in one of the two. NaN points are never on the front."""
    q = np.asarray(quality, dtype=float)
    return nondominated(np.c_[np.asarray(seconds, dtype=float), q if lower_is_better else -q])


def _save(fig, path: Path) -> Path:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format="png", dpi=100, bbox_inches="tight")
    plt.close(fig)
    return path


def _metric_panels(df: pd.DataFrame, metrics) -> tuple[list[str], plt.Figure, np.ndarray]:
    """The metrics ``df`` has values for, and one panel per metric in a row."""
    metrics = [m for m in metrics if m in df.columns and df[m].notna().any()]
    fig, axes = plt.subplots(1, max(1, len(metrics)), figsize=(5.2 * max(1, len(metrics)), 4),
                             squeeze=False)
    if not metrics:
        axes[0, 0].text(0.5, 0.5, "no quality values", ha="center", va="center")
    return metrics, fig, axes


def _seconds_axes(ax, seconds: pd.Series, xlabel: str, ylabel: str) -> None:
    """A panel's seconds axis (log when every value is positive and there are two or more),
    labels, grid and legend."""
    if (seconds > 0).all() and len(seconds) > 1:
        ax.set_xscale("log")
        ax.xaxis.set_minor_formatter(mticker.NullFormatter())  # no overlapping 2x10^2...
        ax.xaxis.set_major_formatter(mticker.FuncFormatter(lambda v, _: f"{v:g}"))
    ax.margins(x=0.25)  # room for the labels of the outermost points
    ax.set_xlabel(xlabel)
    ax.set_ylabel(ylabel)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="best")


def accuracy_vs_time(df: pd.DataFrame, path: Path, metrics=("psnr", "ssim"),
                     seconds="seconds", label="setting", highlight: str | None = None,
                     title: str = "",
                     xlabel: str = "training wall-clock seconds (Snakemake benchmark)",
                     lower_is_better: tuple[str, ...] = (),
                     highlight_label: str = "make demo",
                     ylabels: dict[str, str] | None = None) -> Path:
    """One panel per metric: quality against wall-clock seconds (log x), the Pareto front as a
    line, the ``highlight`` setting (the demo configuration) as a star. Metrics named in
    ``lower_is_better`` are errors: their front is the lower envelope."""
    if "smplx_source" in df.columns and df["smplx_source"].nunique() > 1:
        # settings trained on another SMPL-X source than most are not like for like: say so
        usual = df["smplx_source"].mode().iloc[0]
        other = (df["smplx_source"] != usual).to_numpy()
        names = [f"{v} ({src} SMPL-X)" if o else str(v)
                 for v, src, o in zip(df[label], df["smplx_source"], other)]
        if highlight is not None:
            highlight = next((n for v, n in zip(df[label], names) if str(v) == highlight),
                             highlight)
        df = df.assign(**{label: names})
    metrics, fig, axes = _metric_panels(df, metrics)
    for ax, m in zip(axes[0], metrics):
        d = df[[seconds, m, label]].dropna(subset=[seconds, m])
        front = pareto_front(d[seconds], d[m], m in lower_is_better)
        ax.scatter(d[seconds], d[m], c="0.55", s=28, label="setting", zorder=2)
        f = d[front].sort_values(seconds)
        ax.step(f[seconds], f[m], where="post", color="tab:red", lw=1.5, zorder=3)
        ax.scatter(f[seconds], f[m], c="tab:red", s=40, label="Pareto front", zorder=4)
        for _, r in d.iterrows():
            ax.annotate(str(r[label]), (r[seconds], r[m]), fontsize=7, xytext=(3, 3),
                        textcoords="offset points")
        if highlight is not None and (d[label] == highlight).any():
            h = d[d[label] == highlight]
            ax.scatter(h[seconds], h[m], marker="*", s=260, facecolor="gold",
                       edgecolor="black", label=f"{highlight_label}: {highlight}", zorder=5)
        _seconds_axes(ax, d[seconds], xlabel, (ylabels or {}).get(m, m.upper()))
    if title:
        fig.suptitle(title)
    return _save(fig, path)


def avatar_fronts(df: pd.DataFrame, path: Path, metrics=("psnr", "ssim")) -> Path:
    """Two versions of the code on one accuracy-versus-time figure (an ``avatar_fronts``
    table): per metric a panel with each code's settings and its Pareto front as a line,
    seconds on a log axis."""
    metrics, fig, axes = _metric_panels(df, metrics)
    styles = {"before": ("0.45", "o", "--"), "after": ("tab:red", "s", "-")}
    for ax, m in zip(axes[0], metrics):
        for code, g in df.groupby("code", sort=False):
            colour, marker, line = styles.get(code, ("tab:blue", "^", ":"))
            d = g.dropna(subset=["seconds", m])
            front = d[pareto_front(d["seconds"], d[m])].sort_values("seconds")
            ax.scatter(d["seconds"], d[m], c=colour, marker=marker, s=34, zorder=3,
                       label=f"{code} ({d['commit'].iloc[0]})" if len(d) else code)
            ax.step(front["seconds"], front[m], where="post", color=colour, ls=line, lw=1.5,
                    zorder=2)
            for _, r in d.iterrows():
                ax.annotate(str(r["setting"]), (r["seconds"], r[m]), fontsize=7,
                            xytext=(3, 3), textcoords="offset points", color=colour)
        _seconds_axes(ax, df["seconds"].dropna(),
                      "training wall-clock seconds (Snakemake benchmark)", m.upper())
    scenes = ", ".join(sorted(df["scene"].unique())) if "scene" in df else ""
    when = ", ".join(sorted(df["measured"].unique())) if "measured" in df else ""
    fig.suptitle(f"{scenes}: the accuracy-versus-time front before and after (one machine, "
                 f"{when})")
    return _save(fig, path)


def regularizer_tradeoff(df: pd.DataFrame, path: Path, title: str = "") -> Path:
    """The regulariser's weight sweep: novel-view PSNR against novel-pose PSNR, one line per
    training budget through its scales (labelled), and PSNR of each split against the scale."""
    fig, (ax, bx) = plt.subplots(1, 2, figsize=(10.4, 4))
    wide = df.pivot_table(index=["iterations", "scale"], columns="split", values="psnr")
    for iters, g in wide.groupby(level="iterations"):
        g = g.droplevel("iterations").sort_index()
        if {"novel_pose", "novel_view"} <= set(g.columns):
            ax.plot(g["novel_pose"], g["novel_view"], marker="o", label=f"{iters} steps")
            for scale, r in g.iterrows():
                ax.annotate(f"x{scale:g}", (r["novel_pose"], r["novel_view"]), fontsize=7,
                            xytext=(3, 3), textcoords="offset points")
        for split in g.columns:
            bx.plot(g.index, g[split], marker="o", label=f"{split}, {iters} steps")
    ax.set_xlabel("novel-pose PSNR (dB)")
    ax.set_ylabel("novel-view PSNR (dB)")
    ax.set_title("trade-off (label: weight scale)")
    bx.set_xlabel("regulariser weight scale (0 = off)")
    bx.set_ylabel("PSNR (dB)")
    for a in (ax, bx):
        a.grid(alpha=0.3)
        if a.lines:
            a.legend(fontsize=7)
    if title:
        fig.suptitle(title)
    return _save(fig, path)


def rule_times(bench: pd.DataFrame, path: Path, top: int = 30) -> Path:
    """Horizontal bars: seconds per benchmarked job (scene/job), longest first."""
    d = bench.sort_values("seconds", ascending=False).head(top)
    names = [f"{s}/{j}" if s else j for s, j in zip(d["scene"], d["job"])]
    fig, ax = plt.subplots(figsize=(7, 0.28 * len(d) + 1.2))
    ax.barh(names[::-1], d["seconds"].to_numpy()[::-1], color="tab:blue")
    ax.set_xlabel("wall-clock seconds")
    ax.grid(axis="x", alpha=0.3)
    return _save(fig, path)


def bars(values: pd.Series, path: Path, xlabel: str, title: str = "") -> Path:
    """Horizontal bars of a labelled series (e.g. ablation SSIM per variant)."""
    fig, ax = plt.subplots(figsize=(6, 0.35 * len(values) + 1.2))
    ax.barh([str(i) for i in values.index[::-1]], values.to_numpy()[::-1], color="tab:green")
    ax.set_xlabel(xlabel)
    if title:
        ax.set_title(title)
    ax.grid(axis="x", alpha=0.3)
    return _save(fig, path)


def training_curves(logs: dict[str, pd.DataFrame], path: Path) -> Path:
    """Training PSNR against training seconds, one line per variant."""
    fig, ax = plt.subplots(figsize=(6, 3.6))
    for name, df in logs.items():
        if {"seconds", "psnr"} <= set(df.columns):
            ax.plot(df["seconds"], df["psnr"], label=name, lw=1)
    ax.set_xlabel("training seconds")
    ax.set_ylabel("train PSNR (dB)")
    ax.grid(alpha=0.3)
    if logs:
        ax.legend(fontsize=7)
    return _save(fig, path)


def signer_track(persons: pd.DataFrame, path: Path, title: str = "") -> Path:
    """Who was taken as the signer, frame by frame: every detected person's mid-hip x (grey)
    and the chosen one's, coloured by how they were taken (a ``persons`` table). One panel
    per view; a jump of the coloured line onto another grey track is a change of person."""
    views = sorted(persons["view"].unique()) or [0]
    fig, axes = plt.subplots(len(views), 1, figsize=(8, 2.6 * len(views) + 0.6),
                             squeeze=False, sharex=True)
    colours = {"tracked": "tab:blue", "appearance": "tab:red"}
    for ax, view in zip(axes[:, 0], views):
        p = persons[persons["view"] == view]
        ax.scatter(p["frame"], p["hip_x"], s=4, color="0.7", label="detected people")
        c = p[p["chosen"]].sort_values("frame")
        ax.plot(c["frame"], c["hip_x"], color="0.3", lw=0.6)
        for how, g in sorted(c.groupby("chosen_by"), key=lambda hg: -len(hg[1])):
            # the rare choices (the rule's, the colours') drawn large, over the tracked ones
            ax.scatter(g["frame"], g["hip_x"], s=7 if how == "tracked" else 30, zorder=3,
                       color=colours.get(how, "tab:green"), label=f"signer: {how} ({len(g)})")
        ax.set_ylabel(f"view {view}: mid-hip x (px)")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, loc="best", markerscale=2)
    axes[-1, 0].set_xlabel("frame")
    if title:
        axes[0, 0].set_title(title)
    return _save(fig, path)
