"""CI's check of the worked example: ``python examples/flowclf/check.py results/flowclf_compare``.

Exits 1 unless the method ran under both of its names (entry point ``flow_knn`` and ``flowclf.method:estimate``) on
every run, with identical rows (the same function, however it is named), no failed row, and a version stamped on
its rows; prints each method's accuracy. No accuracy is required: the example shows what a comparison in the
harness looks like, it is not a target.
"""

import sys
from pathlib import Path

import pandas as pd

NAMES = ("flow_knn", "flowclf.method:estimate")


def main(results: str) -> int:
    rows = pd.read_csv(Path(results) / "runs.csv", keep_default_na=False)
    problems = []
    by_name = {n: rows[rows["method"] == n].set_index("run_key").sort_index() for n in NAMES}
    runs = rows["run_key"].nunique()
    for name, table in by_name.items():
        if len(table) != runs:
            problems.append(f"{name}: {len(table)} rows for {runs} runs")
        if (table.get("failed", pd.Series(dtype=str)) != "").any():
            problems.append(f"{name}: failed rows: {sorted(set(table['failed']) - {''})}")
        if (table.get("method_version", pd.Series([""])) == "").any():
            problems.append(f"{name}: rows without method_version")
    scored = [c for c in rows.columns if c not in ("method", "ms_per_frame")]
    a, b = (by_name[n][[c for c in scored if c != "run_key"]] for n in NAMES)
    if not a.equals(b):
        problems.append("the rows of flow_knn and flowclf.method:estimate differ")
    for method, g in rows.groupby("method", sort=False):
        correct = pd.to_numeric(g["correct"], errors="coerce")
        print(f"{method}: accuracy {correct.mean():.3f} over {correct.notna().sum()} runs")
    for p in problems:
        print(f"flowclf check: {p}", file=sys.stderr)
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1] if len(sys.argv) > 1 else "results/flowclf_compare"))
