"""Two evaluations of the same runs, compared run by run (``harness compare A B``).

The way to tell whether a change to the engine (its code, or an ``engine:`` setting) helps: evaluate the same
scenario before and after, into two results directories, and compare them here. A scenario's seed fixes every
run's draws (test motion, camera, markers, noise), so the same run key holds the same observations in both,
and the difference per run is the change's alone. Per scenario, condition and method, and pooled over the
conditions:

- recognition: accuracy in A and in B, the runs only B recognises (*fixed*) and only A (*lost*), and the exact
  McNemar test of those discordant runs (``stats.mcnemar_exact``);
- the pose (``PAIRED_METRICS``): the means in A and B, and the mean of the paired difference B - A with its
  standard error (the runs' differences' standard deviation over the square root of their number).

Runs pair by scenario name, condition, run key and method; a pair whose run seeds differ is not the same run
(another scenario seed), and is refused.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from harness.evaluation.journal import ResultsError
from harness.evaluation.stats import mcnemar_exact
from harness.evaluation.tables import markdown

KEY = ["scenario", "condition", "run_key", "method"]
PAIRED_METRICS = ("heading_err_deg", "base_pos_err_m", "mpjpe_cam_mm", "frame_accuracy")
POOLED = "(pooled)"


def load_evaluation(directory: str | Path) -> pd.DataFrame:
    """Every stored run of a scenario's results directory (one holding ``runs.jsonl``), or of every scenario
    directory inside a results root."""
    from harness.evaluation.runner import load_rows

    directory = Path(directory)
    if (directory / "runs.jsonl").is_file():
        found = [directory]
    else:
        found = sorted(p.parent for p in directory.glob("*/runs.jsonl") if p.is_file())
    if not found:
        raise ResultsError(f"{directory}: no runs.jsonl in it or in its subdirectories (give a scenario's results "
                           "directory, or a results root)")
    rows = pd.concat([load_rows(d) for d in found], ignore_index=True)
    if rows.empty:
        raise ResultsError(f"{directory}: no stored runs")
    return rows


def paired_runs(a: pd.DataFrame, b: pd.DataFrame) -> pd.DataFrame:
    """The runs of ``a`` and ``b`` paired (``KEY``; columns suffixed ``_a`` and ``_b``)."""
    joined = a.merge(b, on=KEY, suffixes=("_a", "_b"))
    if joined.empty:
        raise ResultsError("the two evaluations share no run (compare evaluations of the same scenario)")
    if "seed_a" not in joined or "seed_b" not in joined:
        raise ResultsError("the runs carry no seed column: cannot tell that they are the same runs")
    other = joined["seed_a"] != joined["seed_b"]
    if other.any():
        first = joined.loc[other.idxmax()]
        raise ResultsError(f"{int(other.sum())} paired rows have other run seeds in the two evaluations (the first: "
                           f"{first['scenario']} {first['run_key']}, {first['seed_a']} against {first['seed_b']}): "
                           "not the same runs; was the scenario's seed changed?")
    return joined


def _numbers(s: pd.Series) -> np.ndarray:
    return pd.to_numeric(s, errors="coerce").to_numpy(dtype=float)


def _row(scenario: str, condition: str, method: str, g: pd.DataFrame) -> dict:
    row = {"scenario": scenario, "condition": condition, "method": method, "runs": len(g)}
    if "correct_a" in g and "correct_b" in g:       # methods that recognise
        correct_a, correct_b = _numbers(g["correct_a"]), _numbers(g["correct_b"])
        both = np.isfinite(correct_a) & np.isfinite(correct_b)
        if both.any():
            test = mcnemar_exact(correct_a[both], correct_b[both])
            row.update({"accuracy_a": correct_a[both].mean(), "accuracy_b": correct_b[both].mean(),
                        "fixed": test["b_only"], "lost": test["a_only"], "mcnemar_p": test["p_value"]})
    for metric in PAIRED_METRICS:
        if f"{metric}_a" not in g or f"{metric}_b" not in g:
            continue
        x, y = _numbers(g[f"{metric}_a"]), _numbers(g[f"{metric}_b"])
        keep = np.isfinite(x) & np.isfinite(y)
        if not keep.any():
            continue
        d = y[keep] - x[keep]
        row.update({f"{metric}_a": x[keep].mean(), f"{metric}_b": y[keep].mean(), f"{metric}_diff": d.mean(),
                    f"{metric}_se": d.std(ddof=1) / np.sqrt(len(d)) if len(d) > 1 else np.nan})
    return row


def compare(a: pd.DataFrame, b: pd.DataFrame, pool_scenarios: bool = False) -> pd.DataFrame:
    """One row per scenario, condition and method, and per scenario and method over all its conditions
    (condition ``POOLED``): the module docstring's numbers (B against A). ``pool_scenarios``: the scenarios'
    runs together, condition by condition (copies of one scenario with other seeds, for instance; the runs still
    pair within their own scenario)."""
    joined = paired_runs(a, b)
    if pool_scenarios:
        names = joined["scenario"].unique()
        joined["scenario"] = f"{len(names)} scenarios" if len(names) > 1 else names[0]
    out = []
    for (scenario, method), g in joined.groupby(["scenario", "method"], sort=False):
        conditions = list(g.groupby("condition", sort=False))
        for condition, h in conditions:
            out.append(_row(scenario, condition, method, h))
        if len(conditions) > 1:
            out.append(_row(scenario, POOLED, method, g))
    return pd.DataFrame(out)


def format_comparison(table: pd.DataFrame) -> str:
    """The comparison as a Markdown table (``tables.markdown``): accuracy A -> B (fixed / lost, McNemar p), and
    each paired metric's means A -> B (mean difference ± standard error)."""
    metrics = [m for m in PAIRED_METRICS if f"{m}_diff" in table]
    recognition = "recognition A -> B (fixed / lost, p)"
    cells = []
    for _, r in table.iterrows():
        row = {"scenario": r["scenario"], "condition": r["condition"], "method": r["method"], "runs": r["runs"],
               recognition: ""}
        if pd.notna(r.get("accuracy_a")):
            row[recognition] = (f"{100 * r['accuracy_a']:.1f} -> {100 * r['accuracy_b']:.1f}% "
                                f"({int(r['fixed'])} / {int(r['lost'])}, p = {r['mcnemar_p']:.2g})")
        for m in metrics:
            row[m] = ("" if pd.isna(r.get(f"{m}_diff")) else
                      f"{r[f'{m}_a']:.3g} -> {r[f'{m}_b']:.3g} ({r[f'{m}_diff']:+.3g} ± {r[f'{m}_se']:.2g})")
        cells.append(row)
    return markdown(pd.DataFrame(cells)).rstrip("\n")
