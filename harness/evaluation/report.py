"""``results/<scenario>/report.md``: the scenario, the headline table, per-class recognition, paired tests,
confusion matrices and plots in one date-free document (identical rows give an identical report except the
timing section, which is reported but is not part of any identity check)."""

from __future__ import annotations

from pathlib import Path

import pandas as pd
import yaml

from harness.evaluation.plots import write_plots
from harness.evaluation.runner import load_rows
from harness.evaluation.scenario import Scenario, scenario_hash
from harness.evaluation.tables import markdown, write_tables
from harness.io import write_text_atomic


def swept_keys(scenario: Scenario) -> list[str]:
    return list(scenario.sweep)


def classes_of(scenario: Scenario, rows: pd.DataFrame) -> list[str]:
    """The class order of tables and plots: the scenario's classes, then any other label seen in the rows."""
    listed = list(scenario.database.classes or (scenario.classes if scenario.database.source == "procedural" else ()))
    seen = sorted(set(rows.get("class_true", [])) - set(listed)) if len(rows) else []
    return listed + seen


def make_report(scenario: Scenario, results_dir: str | Path, rows: pd.DataFrame | None = None,
                plots: bool = True) -> Path:
    """Write every table, plot and ``report.md`` of a scenario's results directory; return the report path."""
    results_dir = Path(results_dir)
    digest = scenario_hash(scenario)
    rows = load_rows(results_dir, digest) if rows is None else rows
    swept, classes = swept_keys(scenario), classes_of(scenario, rows)
    if not len(rows):
        text = f"# {scenario.name}\n\nNo finished runs under scenario hash `{digest}`.\n"
        path = results_dir / "report.md"
        write_text_atomic(path, text)
        return path
    tables = write_tables(rows, results_dir, swept, classes, seed=scenario.seed)
    figures = write_plots(rows, results_dir, swept, classes) if plots else []
    n_runs = rows["run_key"].nunique()
    parts = [
        f"# Evaluation: {scenario.name}\n",
        f"{n_runs} runs ({rows['condition'].nunique()} conditions x {scenario.repeats} repeats x test motions), "
        f"methods: {', '.join(dict.fromkeys(rows['method']))}. Scenario hash `{digest}`. Values are means with "
        f"95% bootstrap intervals over runs; `correct` is the final recognition accuracy (0-1).\n",
        "## Headline\n", markdown(tables["headline"]),
        "## Recognition per class\n", markdown(tables["per_class"]),
        "## Paired tests (same runs)\n",
        "Exact McNemar test on final recognition and Wilcoxon signed-rank test on root-relative MPJPE, "
        "`full` against each other method within each condition.\n",
        markdown(tables["paired_tests"]),
        "## Confusion matrices\n",
    ]
    for (cond, method), mat in tables["_confusion_matrices"].items():
        parts += [f"**{method}**, condition `{cond}` (rows: true, columns: predicted)\n",
                  markdown(mat.reset_index().rename(columns={"index": "true"}))]
    if figures:
        parts.append("## Plots\n")
        parts += [f"![{Path(f).stem}]({f})\n" for f in figures]
    parts += ["## Scenario\n", "```yaml\n" + yaml.safe_dump(scenario.model_dump(mode="json"), sort_keys=False)
              + "```\n",
              "## Timing (reported, not part of identity checks)\n", markdown(tables["timing"])]
    path = results_dir / "report.md"
    write_text_atomic(path, "\n".join(parts))
    return path
