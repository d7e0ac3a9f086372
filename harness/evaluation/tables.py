"""Tables from the run rows: per condition and method summaries with bootstrap intervals, per-class recognition,
confusion matrices, paired tests between methods, and the pooled metrics CI compares. CSV and Markdown.

Input is the runner's table (one row per run and method, columns as listed in ``docs/evaluation.md``). Every
table is sorted deterministically and every number formatted the same way, so identical rows give identical
files. Timing (``ms_per_frame``) is reported but kept in its own columns so that identity checks can drop it.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pandas as pd

from harness.evaluation.cache import stable_hash
from harness.evaluation.calibration import calibration_table, pooled_calibration, reliability_table
from harness.evaluation.methods import CURVE_POINTS, known, method_names, produces
from harness.evaluation.stats import N_BOOT, bootstrap_ci, mcnemar_exact, wilcoxon_paired
from harness.io import write_text_atomic

RECOGNITION = ("correct", "frame_accuracy", "time_to_correct_s", "log_p_true")
STREAM = ("edit_score", "f1_10", "f1_25", "f1_50", "boundary_delay_s")      # with frame_accuracy: streams
REPRODUCTION = ("repro_dtw_deg", "repro_dtw_mm", "mean_dtw_deg", "mean_dtw_mm", "repro_beats_mean")
RECOVERY = ("angle_rms_deg", "mpjpe_pose_mm", "mpjpe_cam_mm", "mpjpe_cam17_mm", "pa_mpjpe_mm", "pa_mpjpe17_mm",
            "mpjpe_abs_mm", "base_pos_err_m", "base_depth_err_m", "base_rot_err_deg", "heading_err_deg",
            "tilt_err_deg", "reproj_px", "heading_err_twin_deg", "on_twin")
SCENE = ("self_occlusion", "obstacle_occlusion", "n_frames", "mean_flows")
TIMING = ("ms_per_frame",)
METRICS = RECOGNITION + STREAM + RECOVERY + REPRODUCTION + SCENE + TIMING
HEADLINE = ("correct", "log_p_true", "mpjpe_cam_mm", "pa_mpjpe_mm", "mpjpe_pose_mm", "base_pos_err_m",
            "heading_err_deg", "heading_err_twin_deg", "on_twin", "tilt_err_deg", "angle_rms_deg", "reproj_px")
STREAM_HEADLINE = ("frame_accuracy", "edit_score", "f1_10", "f1_25", "f1_50", "boundary_delay_s", "mpjpe_cam_mm",
                   "base_pos_err_m", "heading_err_deg")


def is_stream(rows: pd.DataFrame) -> bool:
    """Whether the rows are of stream runs (scored per frame, ``harness.evaluation.stream_metrics``)."""
    return "edit_score" in rows.columns


def _given(method: str) -> tuple[str, ...]:
    """The columns a method is handed rather than estimating (none for a method not known in this process)."""
    m = known(method)
    return () if m is None else m.given


def _method_rank(m: str) -> int:
    """Registration order of the methods (``harness.evaluation.methods``); unknown names last."""
    order = method_names()
    return order.index(m) if m in order else len(order)


def _order(df: pd.DataFrame, by: list[str]) -> pd.DataFrame:
    """Sort by condition (first appearance in run-key order), then method in the canonical order, then ``by``."""
    if not len(df):
        return df
    cond_rank = {c: i for i, c in enumerate(dict.fromkeys(df["condition"]))} if "condition" in df else {}
    key = df.assign(_c=df["condition"].map(cond_rank) if cond_rank else 0,
                    _m=df["method"].map(_method_rank) if "method" in df else 0)
    return key.sort_values(["_c", "_m", *by], kind="stable").drop(columns=["_c", "_m"]).reset_index(drop=True)


def summary(rows: pd.DataFrame, swept: list[str], n_boot: int = N_BOOT, seed: int = 0) -> pd.DataFrame:
    """Long table: condition, swept keys, method, metric, n (finite values), mean, std (ddof=1), ci_lo, ci_hi.

    The bootstrap generator is seeded per (condition, method, metric) from ``seed``, so that every cell is
    reproducible on its own and does not depend on which other cells exist.
    """
    out = []
    rows = rows.assign(_c=pd.Categorical(rows["condition"], list(dict.fromkeys(rows["condition"]))))
    for (cond, method), g in rows.groupby(["_c", "method"], sort=False, observed=True):
        first = g.iloc[0]
        for metric in METRICS:
            if metric not in g:
                continue
            x = pd.to_numeric(g[metric], errors="coerce").to_numpy(dtype=float)
            x = x[np.isfinite(x)]
            rng = np.random.default_rng(np.random.SeedSequence(
                [seed, int(stable_hash([str(cond), method, metric])[:8], 16)]))
            lo, hi = bootstrap_ci(x, rng, n_boot)
            out.append({"condition": cond, **{k: first[k] for k in swept}, "method": method, "metric": metric,
                        "n": len(x), "mean": float(np.mean(x)) if len(x) else math.nan,
                        "std": float(np.std(x, ddof=1)) if len(x) > 1 else math.nan, "ci_lo": lo, "ci_hi": hi})
    return _order(pd.DataFrame(out), ["metric"]) if out else pd.DataFrame(out)


def recognising(rows: pd.DataFrame) -> pd.DataFrame:
    """The rows of methods that recognise one class per run (a registered method without recognition has no class
    rows; stream runs have none either), less the rows whose method failed (no answer: ``failed``)."""
    if not len(rows) or is_stream(rows):
        return rows.iloc[0:0]
    answered = rows["failed"].fillna("").astype(str) == "" if "failed" in rows else True
    return rows[np.array([produces(m, "correct") for m in rows["method"]], dtype=bool) & answered]


def per_class(rows: pd.DataFrame) -> pd.DataFrame:
    """Recognition per condition, method and true class: runs, accuracy, frame accuracy, time to correct (s);
    methods that recognise only."""
    if not len(recognising(rows)):
        return pd.DataFrame(columns=["condition", "method", "class_true", "runs", "accuracy", "frame_accuracy",
                                     "time_to_correct_s"])
    g = recognising(rows).groupby(["condition", "method", "class_true"], sort=False)
    out = g.agg(runs=("correct", "size"), accuracy=("correct", "mean"), frame_accuracy=("frame_accuracy", "mean"),
                time_to_correct_s=("time_to_correct_s", "mean")).reset_index()
    return _order(out, ["class_true"])


def class_accuracy(rows: pd.DataFrame) -> pd.DataFrame:
    """Per condition and true class, each recognising method's ``right/runs`` (one column per method): the
    per-class table the report prints."""
    table = per_class(rows)
    if not len(table):
        return pd.DataFrame(columns=["condition", "class_true"])
    table = table.assign(cell=[f"{round(a * n)}/{n}" for a, n in zip(table["accuracy"], table["runs"])])
    wide = table.pivot_table(index=["condition", "class_true"], columns="method", values="cell", aggfunc="first",
                             sort=False).reset_index()
    methods = sorted(set(table["method"]), key=_method_rank)
    return wide[["condition", "class_true", *methods]].rename_axis(columns=None)


def answers(rows: pd.DataFrame) -> pd.DataFrame:
    """Per condition, recognising method and answered class: how often it was the answer (``answered``), for
    a motion of that class (``right``) and of another (``for_others``), and which true classes those others
    were (``from``, most first): the classes a database answers for whatever it does not know. Sorted by
    ``for_others``, most first."""
    g = recognising(rows)
    out = []
    if "class_pred" not in g:           # streams are scored per frame (segments, not one answer)
        g = g.iloc[:0].assign(class_pred=[])
    g = g[g["class_pred"].astype(str) != ""]
    for (cond, method), grp in g.groupby(["condition", "method"], sort=False):
        for pred, sub in grp.groupby("class_pred", sort=False):
            wrong = sub[sub["class_true"] != pred]
            counts = wrong["class_true"].value_counts()
            out.append({"condition": cond, "method": method, "answer": pred, "answered": len(sub),
                        "right": int((sub["class_true"] == pred).sum()), "for_others": len(wrong),
                        "from": ", ".join(f"{c} {n}" for c, n in sorted(counts.items(), key=lambda kv: (-kv[1], kv[0])))})
    table = pd.DataFrame(out, columns=["condition", "method", "answer", "answered", "right", "for_others", "from"])
    return _order(table.assign(_o=-table["for_others"]), ["_o", "answer"]).drop(columns="_o") if len(table) else table


def confusion(rows: pd.DataFrame, classes: list[str]) -> dict[tuple[str, str], pd.DataFrame]:
    """Count matrices (true class rows x predicted class columns) per (condition, method); methods that
    recognise only."""
    out = {}
    for (cond, method), g in _order(recognising(rows), ["run_key"]).groupby(["condition", "method"], sort=False):
        labels = list(classes) + sorted(set(g["class_pred"]) - set(classes))
        m = pd.crosstab(pd.Categorical(g["class_true"], labels), pd.Categorical(g["class_pred"], labels),
                        dropna=False)
        m.index.name, m.columns.name = "true", "predicted"
        out[(cond, method)] = m
    return out


def paired_tests(rows: pd.DataFrame, reference: str = "full") -> pd.DataFrame:
    """Per condition, ``reference`` against every other method over the same runs: exact McNemar on final
    recognition, Wilcoxon signed-rank on camera-frame MPJPE (protocol 1) (where both methods produce it)."""
    out = []
    for cond, g in rows.groupby("condition", sort=False):
        wide = {m: s.set_index("run_key") for m, s in g.groupby("method")}
        if reference not in wide:
            continue
        ref = wide[reference]
        for other in sorted(set(wide) - {reference}, key=_method_rank):
            o = wide[other]
            common = ref.index.intersection(o.index).sort_values()
            # A method without recognition (no_database) has no 'correct' to compare, nor has a stream.
            recognises = "correct" in o and pd.to_numeric(o.loc[common, "correct"], errors="coerce").notna().any()
            if recognises:
                mc = mcnemar_exact(ref.loc[common, "correct"], o.loc[common, "correct"])
                out.append({"condition": cond, "comparison": f"{reference} vs {other}", "test": "McNemar (exact)",
                            "metric": "correct", "n_pairs": mc["n_pairs"],
                            "effect": f"{reference} only right {mc['a_only']}, {other} only right {mc['b_only']}",
                            "p_value": mc["p_value"]})
            if "mpjpe_cam_mm" in ref and "mpjpe_cam_mm" in o:
                w = wilcoxon_paired(ref.loc[common, "mpjpe_cam_mm"], o.loc[common, "mpjpe_cam_mm"])
                if w["n_pairs"]:
                    out.append({"condition": cond, "comparison": f"{reference} vs {other}",
                                "test": "Wilcoxon signed-rank", "metric": "mpjpe_cam_mm", "n_pairs": w["n_pairs"],
                                "effect": f"median difference {_fmt(w['median_diff'])} mm",
                                "p_value": w["p_value"]})
    return pd.DataFrame(out)


def pooled_metrics(rows: pd.DataFrame) -> dict[str, float]:
    """``{"<method>/<metric>": mean over every run of every condition}``, and the calibration of the final
    posterior over those runs (``harness.evaluation.calibration``): what ``harness regress`` compares."""
    out = pooled_calibration(rows)
    for method, g in rows.groupby("method"):
        for metric in RECOGNITION + STREAM + RECOVERY + REPRODUCTION + TIMING:
            if metric in g:
                x = pd.to_numeric(g[metric], errors="coerce").to_numpy(dtype=float)
                x = x[np.isfinite(x)]
                if len(x):
                    out[f"{method}/{metric}"] = float(np.mean(x))
    return dict(sorted(out.items()))


def _fmt(x) -> str:
    """Three significant figures; ``–`` for a missing number."""
    if isinstance(x, str):
        return x
    if x is None or (isinstance(x, (float, np.floating)) and not math.isfinite(x)):
        return "–"
    if isinstance(x, (int, np.integer)):
        return str(int(x))
    return f"{float(x):.3g}"


def markdown(df: pd.DataFrame) -> str:
    """A GitHub Markdown table of ``df`` with numbers at 3 significant figures."""
    if not len(df):
        return "_(no rows)_\n"
    cols = [str(c) for c in df.columns]
    lines = ["| " + " | ".join(cols) + " |", "|" + "|".join("---" for _ in cols) + "|"]
    for row in df.itertuples(index=False):
        lines.append("| " + " | ".join(_fmt(v) for v in row) + " |")
    return "\n".join(lines) + "\n"


def headline(summ: pd.DataFrame, swept: list[str], metrics: tuple[str, ...] = HEADLINE) -> pd.DataFrame:
    """Wide table: one row per condition and method, ``mean [ci_lo, ci_hi]`` per metric (3 significant
    figures), ``given`` where the method is handed the quantity, ``–`` where it does not produce it, and the
    run count."""
    if not len(summ):
        return summ
    rows = []
    for (cond, method), g in summ.groupby(["condition", "method"], sort=False):
        g = g.set_index("metric")
        given = _given(method)
        row = {"condition": cond, **{k: g.iloc[0][k] for k in swept}, "method": method,
               # a table of a few metrics (timing) lacks n_frames: its runs are those that measured them
               "runs": int(g.loc["n_frames", "n"] if "n_frames" in g.index else g["n"].max())}
        for m in metrics:
            if m in given:
                row[m] = "given"
            elif not produces(method, m):
                row[m] = "–"
            elif m in g.index and g.loc[m, "n"] > 0:
                r = g.loc[m]
                row[m] = f"{_fmt(r['mean'])} [{_fmt(r['ci_lo'])}, {_fmt(r['ci_hi'])}]"
            else:
                row[m] = "–"
        rows.append(row)
    return pd.DataFrame(rows)


def accuracy_over_time(rows: pd.DataFrame) -> pd.DataFrame:
    """Recognition against time since the start of the motion: per condition, recognising method and fraction
    of the clip (``accuracy_curve``'s instants), the fraction of runs whose argmax is the true class."""
    if "accuracy_curve" not in rows or not len(rows):
        return pd.DataFrame(columns=["condition", "method", "fraction", "accuracy", "runs"])
    out = []
    for (cond, method), g in _order(recognising(rows), ["run_key"]).groupby(["condition", "method"], sort=False):
        curves = np.array([c for c in g["accuracy_curve"] if isinstance(c, list) and len(c) == CURVE_POINTS],
                          dtype=float).reshape(-1, CURVE_POINTS)
        if not len(curves):
            continue
        for k, frac in enumerate(np.linspace(0.0, 1.0, CURVE_POINTS)):
            out.append({"condition": cond, "method": method, "fraction": round(float(frac), 3),
                        "accuracy": float(curves[:, k].mean()), "runs": len(curves)})
    return pd.DataFrame(out, columns=["condition", "method", "fraction", "accuracy", "runs"])


def heading_over_time(rows: pd.DataFrame) -> pd.DataFrame:
    """The baselink's heading error against time since the start of the motion: per condition, method that
    estimates the base pose and fraction of the clip (``heading_curve``'s instants), the median over runs (deg)
    and its 25-75% range."""
    cols = ["condition", "method", "fraction", "heading_err_median_deg", "q25", "q75", "runs"]
    if "heading_curve" not in rows or not len(rows):
        return pd.DataFrame(columns=cols)
    out = []
    for (cond, method), g in _order(rows, ["run_key"]).groupby(["condition", "method"], sort=False):
        curves = np.array([c for c in g["heading_curve"] if isinstance(c, list) and len(c) == CURVE_POINTS],
                          dtype=float).reshape(-1, CURVE_POINTS)
        if not len(curves):
            continue
        q25, med, q75 = np.percentile(curves, [25, 50, 75], axis=0)
        for k, frac in enumerate(np.linspace(0.0, 1.0, CURVE_POINTS)):
            out.append({"condition": cond, "method": method, "fraction": round(float(frac), 3),
                        "heading_err_median_deg": float(med[k]), "q25": float(q25[k]), "q75": float(q75[k]),
                        "runs": len(curves)})
    return pd.DataFrame(out, columns=cols)


def worst_runs(rows: pd.DataFrame, method: str = "full", n: int = 3) -> pd.DataFrame:
    """The ``n`` worst runs of ``method``: wrong before right, then the lowest log posterior of the true class,
    then the largest camera-frame MPJPE."""
    cols = ["run_key", "condition", "class_true", "class_pred", "correct", "log_p_true", "mpjpe_cam_mm"]
    g = rows[rows["method"] == method] if len(rows) else rows
    if not len(g):
        return pd.DataFrame(columns=cols)
    if is_stream(g):        # streams: the lowest frame accuracy, then the lowest F1@25
        cols = ["run_key", "condition", "frame_accuracy", "edit_score", "f1_25", "boundary_delay_s", "mpjpe_cam_mm"]
        key = g.assign(_a=pd.to_numeric(g["frame_accuracy"], errors="coerce").fillna(-np.inf),
                       _f=pd.to_numeric(g["f1_25"], errors="coerce").fillna(-np.inf))
        return key.sort_values(["_a", "_f", "run_key"], kind="stable").head(n)[cols].reset_index(drop=True)
    key = g.assign(_c=pd.to_numeric(g["correct"], errors="coerce").fillna(0.0),
                   _l=pd.to_numeric(g["log_p_true"], errors="coerce").fillna(-np.inf),
                   _e=-pd.to_numeric(g["mpjpe_cam_mm"], errors="coerce").fillna(np.inf))
    worst = key.sort_values(["_c", "_l", "_e", "run_key"], kind="stable").head(n)
    return worst[[c for c in cols if c in worst]].reset_index(drop=True)


VIEW_METRICS = ("correct", "frame_accuracy", "heading_err_deg", "heading_err_twin_deg")


def by_view(rows: pd.DataFrame, n_boot: int = N_BOOT, seed: int = 0) -> pd.DataFrame:
    """Long table of recognition and heading error against the viewing direction, all conditions pooled:
    view (``viewing.VIEW_BINS`` of ``|view_azimuth_deg|``: front, side, back), method, metric, n, mean, 95%
    bootstrap interval (seeded per cell as in ``summary``); a method's ``given`` columns (the base pose handed to
    ``gt_base``) are left out. Empty for rows without ``view_azimuth_deg``."""
    from harness.evaluation.viewing import VIEW_BINS, view_bin

    cols = ["view", "method", "metric", "n", "mean", "ci_lo", "ci_hi"]
    if "view_azimuth_deg" not in rows or not len(rows):
        return pd.DataFrame(columns=cols)
    views = view_bin(pd.to_numeric(rows["view_azimuth_deg"], errors="coerce").to_numpy(float))
    out = []
    for view, _, _ in VIEW_BINS:
        for method, g in rows[views == view].groupby("method", sort=False):
            given = _given(method)
            for metric in VIEW_METRICS:
                if metric not in g or metric in given or (metric == "frame_accuracy" and "correct" in g
                                                          and not is_stream(g)):
                    continue
                x = pd.to_numeric(g[metric], errors="coerce").to_numpy(dtype=float)
                x = x[np.isfinite(x)]
                if not len(x):
                    continue
                rng = np.random.default_rng(np.random.SeedSequence(
                    [seed, int(stable_hash(["view", view, method, metric])[:8], 16)]))
                lo, hi = bootstrap_ci(x, rng, n_boot)
                out.append({"view": view, "method": method, "metric": metric, "n": len(x),
                            "mean": float(np.mean(x)), "ci_lo": lo, "ci_hi": hi})
    table = pd.DataFrame(out, columns=cols)
    if len(table):
        rank = {v: i for i, (v, _, _) in enumerate(VIEW_BINS)}
        table = table.assign(_v=table["view"].map(rank), _m=table["method"].map(_method_rank)).sort_values(
            ["_m", "metric", "_v"], kind="stable").drop(columns=["_v", "_m"]).reset_index(drop=True)
    return table


# The heading errors (deg) that split the runs in ``pose_error_split``: issue 21's heading target, and an error
# more than twice it.
HEADING_NEAR_DEG, HEADING_FAR_DEG = 20.0, 45.0


def _estimated_pose_groups(rows: pd.DataFrame, need: tuple[str, ...], cols: list[str], least: int, one):
    """``one(x)``'s row (a dict) for each condition and method that estimates the base pose (not handed the
    heading), ``x`` its runs' ``need`` columns as numbers without missing values, if it has at least ``least``
    such runs; the rows ordered as every table (``_order``), with the columns ``cols``. Empty for rows without
    the ``need`` columns."""
    if not len(rows) or any(c not in rows for c in need):
        return pd.DataFrame(columns=cols)
    out = []
    for (cond, method), g in rows.groupby(["condition", "method"], sort=False):
        if "heading_err_deg" in _given(method):
            continue
        x = g[list(need)].apply(pd.to_numeric, errors="coerce").dropna()
        if len(x) >= least:
            out.append({"condition": cond, "method": method, "n": len(x), **one(x)})
    return _order(pd.DataFrame(out, columns=cols), []) if out else pd.DataFrame(columns=cols)


def pose_error_split(rows: pd.DataFrame) -> pd.DataFrame:
    """What the camera-frame joint error is made of, per condition and method that estimates the base pose:
    mean ``mpjpe_cam_mm`` and ``mpjpe_pose_mm`` (the posture alone); the Pearson correlation over runs of
    ``mpjpe_cam_mm`` with the baselink's rotation error and with its depth error (``mpjpe_cam_mm`` subtracts
    the root, so the baselink's position does not enter it, its orientation does); and the runs whose mean
    heading error is within ``HEADING_NEAR_DEG`` and beyond ``HEADING_FAR_DEG``, with their mean
    ``mpjpe_cam_mm``. Empty for rows without these columns."""
    cols = ["condition", "method", "n", "mpjpe_cam_mm", "mpjpe_pose_mm", "corr_rotation", "corr_depth",
            "n_near", "mpjpe_cam_near", "n_far", "mpjpe_cam_far"]
    need = ("mpjpe_cam_mm", "mpjpe_pose_mm", "base_rot_err_deg", "base_depth_err_m", "heading_err_deg")

    def one(x: pd.DataFrame) -> dict:
        near, far = x[x["heading_err_deg"] <= HEADING_NEAR_DEG], x[x["heading_err_deg"] > HEADING_FAR_DEG]
        return {"mpjpe_cam_mm": x["mpjpe_cam_mm"].mean(), "mpjpe_pose_mm": x["mpjpe_pose_mm"].mean(),
                "corr_rotation": x["mpjpe_cam_mm"].corr(x["base_rot_err_deg"]),
                "corr_depth": x["mpjpe_cam_mm"].corr(x["base_depth_err_m"]),
                "n_near": len(near), "mpjpe_cam_near": near["mpjpe_cam_mm"].mean() if len(near) else np.nan,
                "n_far": len(far), "mpjpe_cam_far": far["mpjpe_cam_mm"].mean() if len(far) else np.nan}
    return _estimated_pose_groups(rows, need, cols, 2, one)


# A run settled on the twin (``heading_spread``): its mean heading error beyond a quarter turn, and within
# ``HEADING_FAR_DEG`` of the depth-reflected mirrored twin (``heading_err_twin_deg``, the error to the nearer of
# the two at every frame).
TWIN_RUN_DEG = 90.0


def heading_spread(rows: pd.DataFrame) -> pd.DataFrame:
    """How the runs' mean heading errors spread, per condition and method that estimates the base pose: their
    mean and median (deg), the share within ``HEADING_NEAR_DEG``, the share settled on the twin (mean heading
    error beyond ``TWIN_RUN_DEG`` and up to the twin within ``HEADING_FAR_DEG``), and the mean over the other
    runs: a mean held up by a tail of twins reads apart from one spread evenly. Empty for rows without the two
    heading columns."""
    cols = ["condition", "method", "n", "heading_mean", "heading_median", "within_20", "on_twin",
            "heading_mean_not_twin"]
    need = ("heading_err_deg", "heading_err_twin_deg")

    def one(x: pd.DataFrame) -> dict:
        heading = x["heading_err_deg"]
        twin = (heading > TWIN_RUN_DEG) & (x["heading_err_twin_deg"] <= HEADING_FAR_DEG)
        return {"heading_mean": heading.mean(), "heading_median": heading.median(),
                "within_20": float((heading <= HEADING_NEAR_DEG).mean()), "on_twin": float(twin.mean()),
                "heading_mean_not_twin": heading[~twin].mean() if (~twin).any() else np.nan}
    return _estimated_pose_groups(rows, need, cols, 1, one)


def known_and_open_set(rows: pd.DataFrame) -> tuple[pd.DataFrame, pd.DataFrame]:
    """The rows of motions of a class the database has, and the open-set rows (``open_set``: a capture row of
    no class it has), which no accuracy or error table counts."""
    if "open_set" not in rows or not len(rows):
        return rows, rows.iloc[0:0]
    unknown = rows["open_set"].fillna(False).astype(bool)
    return rows[~unknown], rows[unknown]


def by_test_set(rows: pd.DataFrame) -> pd.DataFrame:
    """Rows whose condition names their test set (``<condition> / <source>``) when they come from several
    (procedural demonstrations and capture sets): every table then reports each set apart."""
    if "source" not in rows or rows["source"].nunique() < 2:
        return rows
    return rows.assign(condition=rows["condition"].astype(str) + " / " + rows["source"].astype(str))


def accuracy_by(rows: pd.DataFrame, column: str) -> pd.DataFrame:
    """Final recognition per condition, recognising method and value of ``column`` (``source``, ``style``,
    ``class_true``): runs, right answers and accuracy."""
    g = recognising(rows)
    if column not in g or not len(g):
        return pd.DataFrame(columns=["condition", "method", column, "runs", "right", "accuracy"])
    correct = pd.to_numeric(g["correct"], errors="coerce")
    out = (g.assign(_c=correct).groupby(["condition", "method", column], sort=False)
           .agg(runs=("_c", "size"), right=("_c", "sum"), accuracy=("_c", "mean")).reset_index())
    out["right"] = out["right"].astype(int)
    return _order(out, [column])


def open_set(rows: pd.DataFrame) -> pd.DataFrame:
    """The open-set rows (motions of no class the database has) per condition, recognising method and true
    label: runs, the answers given (most first) and the mean and largest confidence."""
    g = recognising(rows)
    cols = ["condition", "method", "class_true", "runs", "answers", "confidence", "confidence_max"]
    if not len(g):
        return pd.DataFrame(columns=cols)
    out = []
    for (cond, method, label), sub in g.groupby(["condition", "method", "class_true"], sort=False):
        counts = sub["class_pred"].astype(str).value_counts()
        conf = pd.to_numeric(sub["confidence"], errors="coerce")
        out.append({"condition": cond, "method": method, "class_true": label, "runs": len(sub),
                    "answers": ", ".join(f"{c} {n}" for c, n in sorted(counts.items(), key=lambda kv: (-kv[1], kv[0]))),
                    "confidence": float(conf.mean()), "confidence_max": float(conf.max())})
    return pd.DataFrame(out, columns=cols)


def auroc(positive: np.ndarray, negative: np.ndarray) -> float:
    """The area under the ROC curve of scores that should be higher for ``positive`` than for ``negative``: the
    probability that a random positive outscores a random negative, ties counting half (NaN without both)."""
    positive, negative = np.asarray(positive, dtype=float), np.asarray(negative, dtype=float)
    if not len(positive) or not len(negative):
        return math.nan
    greater = (positive[:, None] > negative[None]).mean()
    ties = (positive[:, None] == negative[None]).mean()
    return float(greater + 0.5 * ties)


def unknown_detection(rows: pd.DataFrame) -> pd.DataFrame:
    """"None of these", per condition and recognising method whose database has a background class (a finite
    ``p_unknown``): runs of known classes and open-set runs, the AUROC of ``p_unknown`` between them, and the
    shares of each answered ``unknown``."""
    cols = ["condition", "method", "known_runs", "open_set_runs", "auroc", "known_answered_unknown",
            "open_set_answered_unknown"]
    g = recognising(rows)
    if "p_unknown" not in g or not len(g) or not pd.to_numeric(g["p_unknown"], errors="coerce").notna().any():
        return pd.DataFrame(columns=cols)
    out = []
    for (cond, method), sub in g.groupby(["condition", "method"], sort=False):
        p = pd.to_numeric(sub["p_unknown"], errors="coerce")
        if not p.notna().any():
            continue
        unknown = sub["open_set"].fillna(False).astype(bool) if "open_set" in sub else pd.Series(False, sub.index)
        answered = sub["class_pred"].astype(str) == "unknown"
        out.append({"condition": cond, "method": method, "known_runs": int((~unknown).sum()),
                    "open_set_runs": int(unknown.sum()), "auroc": auroc(p[unknown], p[~unknown]),
                    "known_answered_unknown": float(answered[~unknown].mean()) if (~unknown).any() else math.nan,
                    "open_set_answered_unknown": float(answered[unknown].mean()) if unknown.any() else math.nan})
    return pd.DataFrame(out, columns=cols)


def write_tables(rows: pd.DataFrame, out_dir: str | Path, swept: list[str], classes: list[str],
                 n_boot: int = N_BOOT, seed: int = 0) -> dict[str, pd.DataFrame]:
    """Write ``summary``, ``headline``, ``per_class``, ``class_accuracy``, ``answers``, ``confusion``,
    ``paired_tests``, ``accuracy_over_time``,
    ``heading_over_time``, ``worst_runs``, ``calibration``, ``reliability``, ``by_view``, ``pose_error_split`` and
    ``heading_spread`` as CSV and Markdown,
    and ``metrics.json`` (pooled metrics), under ``out_dir``; with capture rows also ``by_source`` and
    ``by_style`` (recognition per set and style) and ``open_set`` (the motions of no class the database has,
    which every other table leaves out). Returns the tables by name."""
    out_dir = Path(out_dir)
    detection = unknown_detection(by_test_set(rows))
    rows, unknown = known_and_open_set(rows)
    extra = {"open_set": open_set(unknown)} if len(unknown) else {}
    if len(detection):
        extra["unknown_detection"] = detection
    for column, name in (("source", "by_source"), ("style", "by_style")):
        if column in rows and rows[column].fillna("").astype(str).ne("").any() and (
                column == "style" or rows[column].nunique() > 1):
            extra[name] = accuracy_by(rows, column)
    rows = by_test_set(rows)
    summ = summary(rows, swept, n_boot, seed)
    timing = summ[summ["metric"].isin(TIMING)] if len(summ) else summ
    if "repro_dtw_deg" in rows:         # reproduction columns next to the others
        head = tuple(dict.fromkeys(REPRODUCTION + (STREAM_HEADLINE if is_stream(rows) else HEADLINE)))
    else:
        head = STREAM_HEADLINE if is_stream(rows) else HEADLINE
    tables = {"summary": summ, "headline": headline(summ, swept, head),
              "per_class": per_class(rows), "class_accuracy": class_accuracy(rows), "answers": answers(rows),
              "paired_tests": paired_tests(rows),
              "timing": headline(timing, swept, TIMING),
              "accuracy_over_time": accuracy_over_time(rows), "heading_over_time": heading_over_time(rows),
              "worst_runs": worst_runs(rows),
              "calibration": calibration_table(rows, swept), "reliability": reliability_table(rows),
              "by_view": by_view(rows, n_boot, seed), "pose_error_split": pose_error_split(rows),
              "heading_spread": heading_spread(rows)}
    tables |= extra
    conf = confusion(rows, classes)
    long = [{"condition": c, "method": m, "true": t, "predicted": p, "count": int(mat.loc[t, p])}
            for (c, m), mat in conf.items() for t in mat.index for p in mat.columns]
    tables["confusion"] = pd.DataFrame(long)
    for name, df in tables.items():
        write_text_atomic(out_dir / f"{name}.csv", df.to_csv(index=False, float_format="%.10g"))
        write_text_atomic(out_dir / f"{name}.md", markdown(df))
    write_text_atomic(out_dir / "metrics.json", json.dumps(pooled_metrics(rows), indent=2) + "\n")
    tables["_confusion_matrices"] = conf   # for the plots and the report; not written as its own file
    return tables
