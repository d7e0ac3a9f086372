"""PNG plots of an evaluation (matplotlib, Agg back-end): metrics against each swept key, accuracy against the
measured occlusion, confusion matrices per method, and reliability diagrams of the final class posterior.

A plot against a swept key pools the runs of every other swept key (the marginal effect of that key); points
are means with 95% bootstrap intervals, one line per method.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pandas as pd

from harness.evaluation.stats import bootstrap_ci

# What to draw against each sweepable key (anything else numeric gets the default pair).
PLOT_METRICS: dict[str, tuple[str, ...]] = {
    "occluders.amount": ("correct", "frame_accuracy", "mpjpe_cam_mm"),
    "markers.count": ("correct", "mpjpe_cam_mm", "angle_rms_deg", "base_pos_err_m"),
    "observation.noise_px": ("correct", "mpjpe_cam_mm", "base_pos_err_m", "reproj_px"),
    "observation.dropout": ("correct", "mpjpe_cam_mm"),
    "observation.outliers": ("correct", "mpjpe_cam_mm"),
    "camera.azimuth": ("correct", "mpjpe_cam_mm", "base_pos_err_m", "heading_err_deg"),
    "camera.elevation": ("correct", "mpjpe_cam_mm", "base_pos_err_m", "heading_err_deg"),
    "camera.distance": ("correct", "mpjpe_cam_mm", "base_depth_err_m"),
    "engine.particles": ("correct", "base_pos_err_m", "mpjpe_cam_mm", "ms_per_frame"),
    "engine.primitive_switch": ("frame_accuracy", "f1_25", "boundary_delay_s"),
}
STREAM_METRICS = ("frame_accuracy", "f1_25", "boundary_delay_s", "mpjpe_cam_mm")   # streams, against other keys
DEFAULT_METRICS = ("correct", "mpjpe_cam_mm")
LABELS = {"correct": "accuracy", "frame_accuracy": "per-frame accuracy", "f1_25": "F1@25",
          "edit_score": "edit score", "boundary_delay_s": "boundary delay (s)", "mpjpe_cam_mm": "MPJPE camera frame (mm)",
          "mpjpe_pose_mm": "MPJPE pose only (mm)", "pa_mpjpe_mm": "PA-MPJPE (mm)",
          "heading_err_deg": "heading error (deg)",
          "mpjpe_abs_mm": "MPJPE abs. (mm)", "angle_rms_deg": "joint angle RMS (deg)",
          "base_pos_err_m": "base position error (m)", "base_depth_err_m": "base depth error (m)",
          "base_rot_err_deg": "base rotation error (deg)", "reproj_px": "reprojection (px)",
          "ms_per_frame": "ms per frame"}


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _save(fig, path: Path) -> None:
    """Lay the figure out, write it as PNG (atomically) and close it."""
    from harness.io import write_atomic

    fig.tight_layout()
    write_atomic(path, lambda fh: fig.savefig(fh, format="png", dpi=100, metadata={"Software": None}))
    _pyplot().close(fig)


def _numeric(values) -> bool:
    return all(isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, bool) for v in values)


def _mean_ci(x: np.ndarray, seed: int) -> tuple[float, float, float]:
    x = x[np.isfinite(x)]
    if not len(x):
        return np.nan, np.nan, np.nan
    lo, hi = bootstrap_ci(x, np.random.default_rng(seed), 1000)
    return float(np.mean(x)), lo, hi


def _colour(method: str) -> str:
    """One colour per method in every panel and plot: matplotlib's default cycle in registration order
    (``harness.evaluation.methods``), skipping C7 (grey), which marks an unregistered name."""
    from harness.evaluation.methods import method_names

    order = method_names()
    if method not in order:
        return "C7"
    k = order.index(method) % 9
    return f"C{k if k < 7 else k + 1}"


def plot_against(rows: pd.DataFrame, key: str, path: Path, seed: int = 0) -> bool:
    """Metrics against swept ``key``, one panel per metric, one line per method; False if nothing to draw."""
    wanted = PLOT_METRICS.get(key, DEFAULT_METRICS)
    if "edit_score" in rows and key != "engine.primitive_switch":
        wanted = STREAM_METRICS
    metrics = [m for m in wanted if m in rows and rows[m].notna().any()]
    values = list(dict.fromkeys(rows[key]))
    if not metrics or not _numeric(values):
        return False
    plt = _pyplot()
    fig, axes = plt.subplots(1, len(metrics), figsize=(4.2 * len(metrics), 3.4), squeeze=False)
    xs = sorted(values)
    for ax, metric in zip(axes[0], metrics):
        for method, g in rows.groupby("method", sort=False):
            stats = [_mean_ci(pd.to_numeric(g.loc[g[key] == v, metric], errors="coerce").to_numpy(float), seed)
                     for v in xs]
            mean, lo, hi = (np.array(s) for s in zip(*stats))
            if np.isfinite(mean).any():
                ax.errorbar(xs, mean, yerr=[mean - lo, hi - mean], marker="o", capsize=3, label=method,
                            color=_colour(method))
        ax.set_xlabel(key)
        ax.set_ylabel(LABELS.get(metric, metric))
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)   # per panel: methods without a metric are absent from its panel
    _save(fig, path)
    return True


def plot_measured_occlusion(rows: pd.DataFrame, path: Path) -> bool:
    """Accuracy per condition against the measured occlusion (self + obstacle, mean over runs); the per-frame
    accuracy for streams."""
    if not {"self_occlusion", "obstacle_occlusion"} <= set(rows) or rows["obstacle_occlusion"].isna().all():
        return False
    metric = "correct" if "correct" in rows else "frame_accuracy"
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(5, 3.6))
    for method, g in rows.groupby("method", sort=False):
        per = g.assign(occ=g["self_occlusion"] + g["obstacle_occlusion"],
                       acc=pd.to_numeric(g[metric], errors="coerce")).groupby("condition", sort=False)
        pts = per.agg(occ=("occ", "mean"), acc=("acc", "mean")).sort_values("occ")
        if pts["acc"].notna().any():
            ax.plot(pts["occ"], pts["acc"], marker="o", label=method, color=_colour(method))
    ax.set_xlabel("measured occlusion (fraction of markers hidden)")
    ax.set_ylabel(LABELS[metric])
    ax.set_ylim(-0.02, 1.02)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    _save(fig, path)
    return True


def plot_confusion(matrix: pd.DataFrame, title: str, path: Path) -> None:
    """A count matrix (true rows x predicted columns) as a row-normalised heat map with the counts written in."""
    plt = _pyplot()
    counts = matrix.to_numpy(dtype=float)
    frac = counts / np.maximum(counts.sum(axis=1, keepdims=True), 1.0)
    n = len(matrix.columns)
    fig, ax = plt.subplots(figsize=(1.0 + 0.55 * n, 0.8 + 0.5 * len(matrix)))
    ax.imshow(frac, cmap="Blues", vmin=0.0, vmax=1.0)
    for (i, j), c in np.ndenumerate(counts):
        if c:
            ax.text(j, i, int(c), ha="center", va="center", fontsize=7, color="white" if frac[i, j] > 0.5 else "black")
    ax.set_xticks(range(n), [str(c) for c in matrix.columns], rotation=60, ha="right", fontsize=8)
    ax.set_yticks(range(len(matrix)), [str(c) for c in matrix.index], fontsize=8)
    ax.set_xlabel("predicted")
    ax.set_ylabel("true")
    ax.set_title(title, fontsize=9)
    _save(fig, path)


def plot_class_heatmap(per_class: pd.DataFrame, classes: list[str], path: Path) -> bool:
    """Final accuracy per true class (rows) and method x condition (columns) as a heat map, values written in."""
    if not len(per_class):
        return False
    plt = _pyplot()
    cols = list(dict.fromkeys(zip(per_class["method"], per_class["condition"])))
    acc = np.full((len(classes), len(cols)), np.nan)
    for r in per_class.itertuples(index=False):
        if r.class_true in classes:
            acc[classes.index(r.class_true), cols.index((r.method, r.condition))] = r.accuracy
    one_condition = len({c for _, c in cols}) == 1
    # The rotated method (and condition) labels need their own height, however few the classes.
    labels_height = 0.8 if one_condition else 1.3
    fig, ax = plt.subplots(figsize=(max(3.6, 1.6 + 0.75 * len(cols)), 0.6 + labels_height + 0.36 * len(classes)))
    ax.imshow(np.nan_to_num(acc, nan=0.0), cmap="RdYlGn", vmin=0.0, vmax=1.0, aspect="auto")
    for (i, j), a in np.ndenumerate(acc):
        ax.text(j, i, "–" if np.isnan(a) else f"{a:.2f}", ha="center", va="center", fontsize=7)
    labels = [m if one_condition else f"{m}\n{c}" for m, c in cols]
    ax.set_xticks(range(len(cols)), labels, rotation=60, ha="right", fontsize=7)
    ax.set_yticks(range(len(classes)), classes, fontsize=8)
    ax.set_title("final recognition accuracy per class", fontsize=9)
    _save(fig, path)
    return True


def plot_accuracy_over_time(curve: pd.DataFrame, path: Path) -> bool:
    """Accuracy against time since the start of the motion (fraction of the clip), one line per method (and
    line style per condition when there are several)."""
    return _plot_over_time(curve, "accuracy", "accuracy of the current argmax", (-0.02, 1.02), path)


def plot_heading_over_time(curve: pd.DataFrame, path: Path) -> bool:
    """The median heading error against time since the start of the motion (``tables.heading_over_time``),
    one line per method (and line style per condition), beside the accuracy over time."""
    return _plot_over_time(curve, "heading_err_median_deg", "median heading error (deg)", (0.0, 180.0), path)


def _plot_over_time(curve: pd.DataFrame, column: str, ylabel: str, ylim: tuple[float, float], path: Path) -> bool:
    if not len(curve):
        return False
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(5.5, 3.6))
    conds = list(dict.fromkeys(curve["condition"]))
    styles = ("-", "--", ":", "-.")
    for (method, cond), g in curve.groupby(["method", "condition"], sort=False):
        k = conds.index(cond)
        label = method if len(conds) == 1 else f"{method}, {cond}"
        ax.plot(g["fraction"], g[column], marker="o", ms=3, color=_colour(method), ls=styles[k % len(styles)],
                label=label)
    ax.set_xlabel("time since the start of the motion (fraction of the clip)")
    ax.set_ylabel(ylabel)
    ax.set_ylim(*ylim)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    _save(fig, path)
    return True


def plot_heading_spread(rows: pd.DataFrame, path: Path) -> bool:
    """The share of runs whose mean heading error is at most each angle (its empirical distribution), per
    condition (a panel each) and method that estimates the base pose; the error up to the twin dashed, and issue
    21's 20 deg marked. False when no method estimates the heading."""
    from harness.evaluation.tables import HEADING_NEAR_DEG, heading_spread

    spread = heading_spread(rows)
    if not len(spread):
        return False
    plt = _pyplot()
    conds = list(dict.fromkeys(spread["condition"]))
    fig, axes = plt.subplots(1, len(conds), figsize=(4.2 * len(conds), 3.6), sharey=True, squeeze=False)
    for ax, cond in zip(axes[0], conds):
        for method in spread.loc[spread["condition"] == cond, "method"]:
            g = rows[(rows["condition"] == cond) & (rows["method"] == method)]
            for column, ls in (("heading_err_deg", "-"), ("heading_err_twin_deg", "--")):
                x = np.sort(pd.to_numeric(g[column], errors="coerce").dropna().to_numpy())
                if len(x):
                    ax.step(np.r_[0.0, x, 180.0], np.r_[0.0, np.arange(1, len(x) + 1) / len(x), 1.0], where="post",
                            color=_colour(method), ls=ls, label=method if ls == "-" else f"{method}, up to the twin")
        ax.axvline(HEADING_NEAR_DEG, color="0.6", lw=1, ls=":")
        ax.set_xlim(0.0, 180.0)
        ax.set_xlabel("mean heading error of a run (deg)")
        ax.set_title(cond, fontsize=9)
        ax.grid(alpha=0.3)
    axes[0][0].set_ylabel("share of runs at most this far off")
    axes[0][0].legend(fontsize=7, loc="lower right")
    _save(fig, path)
    return True


def plot_reliability(rel: pd.DataFrame, path: Path) -> bool:
    """Reliability diagrams: per recognising method (one panel each), the accuracy of each equal-mass bin
    against its mean confidence (marker area by runs), the run count written beside it, and the diagonal of a
    calibrated posterior (``calibration.reliability_table``: all conditions pooled). Bins drawn at the same
    spot (several bins of confidence 1.00) get one label, their summed count, so that labels do not overprint."""
    if not len(rel):
        return False
    plt = _pyplot()
    methods = list(dict.fromkeys(rel["method"]))
    fig, axes = plt.subplots(1, len(methods), figsize=(3.3 * len(methods), 3.5), squeeze=False)
    for ax, method in zip(axes[0], methods):
        g = rel[rel["method"] == method]
        ax.plot([0, 1], [0, 1], color="0.6", lw=1, ls="--")
        ax.plot(g["confidence"], g["accuracy"], color=_colour(method), lw=1)
        ax.scatter(g["confidence"], g["accuracy"], s=12 + 200 * g["runs"] / g["runs"].sum(), color=_colour(method),
                   zorder=3)
        spots = g.assign(x=g["confidence"].round(2), y=g["accuracy"].round(2)).groupby(["x", "y"], sort=False)
        for (x, y), n in spots["runs"].sum().items():
            ax.annotate(str(int(n)), (x, y), textcoords="offset points", xytext=(-12, 5), fontsize=7)
        ax.set_xlim(-0.02, 1.04)
        ax.set_ylim(-0.02, 1.04)
        ax.set_xlabel("confidence (bin mean)")
        ax.set_ylabel("accuracy")
        ax.set_title(f"{method}: ECE {g['ece'].iloc[0]:.3f}, {int(g['runs'].sum())} runs", fontsize=9)
        ax.grid(alpha=0.3)
    _save(fig, path)
    return True


def plot_by_view(table: pd.DataFrame, path: Path) -> bool:
    """Recognition and heading error against the viewing direction (``tables.by_view``: front, side, back of
    the camera's azimuth from the subject's initial heading), one line per method, 95% intervals; the heading
    error up to the twin dashed beside the plain one. False when there is nothing to draw."""
    if not len(table):
        return False
    from harness.evaluation.viewing import VIEW_BINS

    views = [v for v, _, _ in VIEW_BINS]
    recognition = "correct" if (table["metric"] == "correct").any() else "frame_accuracy"
    panels = [(recognition, (recognition,)), ("heading_err_deg", ("heading_err_deg", "heading_err_twin_deg"))]
    panels = [(name, ms) for name, ms in panels if table["metric"].isin(ms).any()]
    if not panels:
        return False
    plt = _pyplot()
    fig, axes = plt.subplots(1, len(panels), figsize=(4.6 * len(panels), 3.6), squeeze=False)
    for ax, (name, metrics) in zip(axes[0], panels):
        for metric in metrics:
            for method, g in table[table["metric"] == metric].groupby("method", sort=False):
                g = g.set_index("view").reindex(views)
                x = np.arange(len(views)) + (0.08 if metric.endswith("twin_deg") else 0.0)
                mean, lo, hi = (g[c].to_numpy(float) for c in ("mean", "ci_lo", "ci_hi"))
                twin = metric.endswith("twin_deg")
                ax.errorbar(x, mean, yerr=[mean - lo, hi - mean], marker="o", capsize=3, color=_colour(method),
                            ls="--" if twin else "-", mfc="white" if twin else None,
                            label=f"{method}, up to the twin" if twin else method)
        ax.set_xticks(range(len(views)), [f"{v}\n|az| {lo:g}-{hi:g} deg" for v, lo, hi in VIEW_BINS], fontsize=8)
        ax.set_xlabel("where the camera stands (azimuth from the initial heading)")
        ax.set_ylabel(LABELS.get(name, name))
        if name in ("correct", "frame_accuracy"):
            ax.set_ylim(-0.02, 1.02)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    _save(fig, path)
    return True


TRANSITION_COLOUR = (0.85, 0.85, 0.85)


def _segments(value) -> list:
    """A row's segment record (``[[label, start, stop], ...]``; a string when read back from CSV)."""
    if isinstance(value, str):
        import ast

        value = ast.literal_eval(value)
    return list(value) if isinstance(value, (list, tuple)) else []


def plot_timeline(run_rows: pd.DataFrame, classes: list[str], fps: float, path: Path) -> bool:
    """One stream run: the true labels over time and, below, each recognising method's online labels, one
    colour per primitive (transitions grey), the method's frame accuracy and F1@25 beside it."""
    from harness.motion.stream import TRANSITION

    rec = run_rows[[len(_segments(v)) > 0 for v in run_rows.get("segments_pred", [])]] \
        if "segments_pred" in run_rows else run_rows.iloc[0:0]
    if not len(run_rows) or "segments_true" not in run_rows:
        return False
    plt = _pyplot()
    import matplotlib

    cmap = matplotlib.colormaps["tab10"]
    colour = {c: cmap(i % 10) for i, c in enumerate(classes)}
    lanes = [("true", _segments(run_rows.iloc[0]["segments_true"]), "")]
    for r in rec.itertuples(index=False):
        lanes.append((r.method, _segments(r.segments_pred),
                      f"frames {r.frame_accuracy:.2f}, F1@25 {r.f1_25:.2f}"))
    end = max(stop for _, segs, _ in lanes for _, _, stop in segs)
    fig, ax = plt.subplots(figsize=(10, 0.55 * len(lanes) + 1.2))
    for y, (_, segs, _) in enumerate(lanes):
        for label, start, stop in segs:
            ax.broken_barh([(start / fps, (stop - start) / fps)], (len(lanes) - 1 - y - 0.4, 0.8),
                           facecolors=TRANSITION_COLOUR if label == TRANSITION else colour.get(label, "k"),
                           edgecolor="white", linewidth=0.5)
            if label != TRANSITION and (stop - start) / end > 0.04:
                ax.text((start + stop) / 2 / fps, len(lanes) - 1 - y, label, ha="center", va="center", fontsize=7)
    ax.set_yticks(range(len(lanes)), [f"{name}\n{note}" if note else name for name, _, note in reversed(lanes)],
                  fontsize=7)
    ax.set_xlim(0, end / fps)
    ax.set_xlabel("time (s)")
    ax.set_title(f"{run_rows.iloc[0]['run_key']}: true labels (top) and recognised labels", fontsize=9)
    _save(fig, path)
    return True


def timeline_name(run_key: str) -> str:
    return "plots/timelines/" + run_key.replace("/", "_") + ".png"


def write_plots(rows: pd.DataFrame, out_dir: str | Path, swept: list[str], classes: list[str], fps: float = 30.0
                ) -> list[str]:
    """Every plot the scenario calls for, under ``out_dir/plots``; returns their paths relative to ``out_dir``.
    ``fps``: the runs' frame rate (the time axis of stream timelines)."""
    from harness.evaluation.calibration import reliability_table
    from harness.evaluation.tables import accuracy_over_time, confusion, heading_over_time, per_class

    out_dir = Path(out_dir)
    made = []
    if "segments_true" in rows:
        for key, g in rows.groupby("run_key", sort=True):
            name = timeline_name(str(key))
            if plot_timeline(g, classes, fps, out_dir / name):
                made.append(name)
    if plot_accuracy_over_time(accuracy_over_time(rows), out_dir / "plots/accuracy_over_time.png"):
        made.append("plots/accuracy_over_time.png")
    if plot_heading_over_time(heading_over_time(rows), out_dir / "plots/heading_over_time.png"):
        made.append("plots/heading_over_time.png")
    if plot_heading_spread(rows, out_dir / "plots/heading_spread.png"):
        made.append("plots/heading_spread.png")
    if plot_class_heatmap(per_class(rows), classes, out_dir / "plots/class_accuracy.png"):
        made.append("plots/class_accuracy.png")
    if plot_reliability(reliability_table(rows), out_dir / "plots/reliability.png"):
        made.append("plots/reliability.png")
    for key in swept:
        name = f"plots/vs_{key.replace('.', '_')}.png"
        if plot_against(rows, key, out_dir / name):
            made.append(name)
    if "occluders.amount" in swept and plot_measured_occlusion(rows, out_dir / "plots/accuracy_vs_measured_occlusion.png"):
        made.append("plots/accuracy_vs_measured_occlusion.png")
    from harness.evaluation.tables import by_view

    if plot_by_view(by_view(rows, 1000), out_dir / "plots/by_view.png"):
        made.append("plots/by_view.png")
    pooled = rows.assign(condition="all conditions")
    for (_, method), mat in confusion(pooled, classes).items():
        # a method from outside is named module.path:function: a file name of the characters every system keeps
        name = "plots/confusion_" + re.sub(r"[^A-Za-z0-9_.-]", "_", method) + ".png"
        plot_confusion(mat, f"{method}: all conditions, {int(mat.to_numpy().sum())} runs", out_dir / name)
        made.append(name)
    return made
