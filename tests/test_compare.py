"""``harness compare``: two evaluations of the same runs, run by run."""

import numpy as np
import pandas as pd
import pytest
from scipy.stats import binomtest

from harness.cli import main
from harness.evaluation.compare import POOLED, compare, load_evaluation
from harness.evaluation.journal import Journal, ResultsError


def _runs(correct, heading, seeds=None, conditions=("c0", "c1"), method="full"):
    """Rows of one scenario: run i in condition ``conditions[i % 2]``."""
    n = len(correct)
    return pd.DataFrame({
        "scenario": "demo", "condition": [conditions[i % len(conditions)] for i in range(n)],
        "run_key": [f"c00{i % len(conditions)}/r{i:03d}/walk/d008" for i in range(n)], "method": method,
        "seed": np.arange(n) if seeds is None else seeds, "correct": correct, "heading_err_deg": heading})


def test_the_numbers_against_a_direct_computation():
    rng = np.random.default_rng(3)
    n = 40
    a_right, b_right = rng.random(n) < 0.7, rng.random(n) < 0.8
    h_a, h_b = rng.uniform(0, 90, n), rng.uniform(0, 90, n)
    table = compare(_runs(a_right.astype(int), h_a), _runs(b_right.astype(int), h_b))
    pooled = table[table["condition"] == POOLED].iloc[0]
    fixed, lost = int(np.sum(~a_right & b_right)), int(np.sum(a_right & ~b_right))
    assert (pooled["runs"], pooled["fixed"], pooled["lost"]) == (n, fixed, lost)
    assert pooled["accuracy_a"] == pytest.approx(a_right.mean()) and pooled["accuracy_b"] == pytest.approx(b_right.mean())
    assert pooled["mcnemar_p"] == pytest.approx(binomtest(min(fixed, lost), fixed + lost, 0.5).pvalue)
    d = h_b - h_a
    assert pooled["heading_err_deg_diff"] == pytest.approx(d.mean())
    assert pooled["heading_err_deg_se"] == pytest.approx(np.std(d, ddof=1) / np.sqrt(n))
    # Each condition on its own runs: the even runs are c0's.
    c0 = table[table["condition"] == "c0"].iloc[0]
    assert c0["runs"] == n // 2 and c0["heading_err_deg_diff"] == pytest.approx(d[::2].mean())
    assert c0["fixed"] == int(np.sum(~a_right[::2] & b_right[::2]))


def test_runs_pair_by_key_not_by_order():
    a = _runs([1, 0, 1, 0], [10.0, 20.0, 30.0, 40.0])
    b = a.iloc[::-1].copy()
    b["heading_err_deg"] = b["heading_err_deg"] + 5.0
    pooled = compare(a, b).query("condition == @POOLED").iloc[0]
    assert pooled["heading_err_deg_diff"] == pytest.approx(5.0) and pooled["heading_err_deg_se"] == pytest.approx(0.0)
    assert pooled["fixed"] == pooled["lost"] == 0


def test_scenarios_pool_condition_by_condition_and_still_pair_within_their_own():
    """Two seed copies of one scenario share run keys: pooled, each run still meets its own counterpart."""
    a1, a2 = _runs([1, 1], [10.0, 20.0]), _runs([0, 0], [30.0, 40.0], seeds=[5, 6])
    a2["scenario"] = "demo2"
    b1, b2 = a1.assign(heading_err_deg=[11.0, 21.0]), a2.assign(heading_err_deg=[33.0, 43.0], correct=[1, 0])
    table = compare(pd.concat([a1, a2]), pd.concat([b1, b2]), pool_scenarios=True)
    assert set(table["scenario"]) == {"2 scenarios"}
    pooled = table[table["condition"] == POOLED].iloc[0]
    assert pooled["runs"] == 4 and pooled["fixed"] == 1 and pooled["lost"] == 0
    assert pooled["heading_err_deg_diff"] == pytest.approx(2.0)
    c0 = table[table["condition"] == "c0"].iloc[0]
    assert c0["runs"] == 2 and c0["heading_err_deg_diff"] == pytest.approx(2.0)   # 1 and 3


def test_a_method_that_does_not_recognise_has_no_accuracy():
    a = _runs([np.nan] * 4, [1.0, 2.0, 3.0, 4.0], method="no_database")
    row = compare(a, a).iloc[0]
    assert pd.isna(row.get("accuracy_a")) and row["heading_err_deg_diff"] == 0.0
    bare = a.drop(columns="correct")          # an evaluation of such methods alone has no column at all
    assert "accuracy_a" not in compare(bare, bare)


def test_other_seeds_or_no_common_run_are_refused():
    a = _runs([1, 1], [1.0, 2.0])
    with pytest.raises(ResultsError, match="not the same runs"):
        compare(a, _runs([1, 1], [1.0, 2.0], seeds=[7, 8]))
    other = _runs([1, 1], [1.0, 2.0])
    other["scenario"] = "another"
    with pytest.raises(ResultsError, match="share no run"):
        compare(a, other)


def _store(directory, rows: pd.DataFrame) -> None:
    with Journal(directory, "h") as journal:
        for key, g in rows.groupby("run_key"):
            journal.append(key, g.to_dict("records"))


def test_the_command_reads_two_results_roots(tmp_path, capsys):
    a, b = _runs([1, 0, 1, 1], [10.0, 20.0, 30.0, 40.0]), _runs([1, 1, 1, 0], [12.0, 20.0, 30.0, 40.0])
    _store(tmp_path / "A" / "demo", a)
    _store(tmp_path / "B" / "demo", b)
    assert len(load_evaluation(tmp_path / "A")) == len(load_evaluation(tmp_path / "A" / "demo")) == 4
    out = tmp_path / "table.csv"
    assert main(["compare", str(tmp_path / "A"), str(tmp_path / "B"), "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "75.0 -> 75.0% (1 / 1, p = 1)" in printed
    written = pd.read_csv(out)
    assert written.loc[written["condition"] == POOLED, "heading_err_deg_diff"].item() == pytest.approx(0.5)
    assert main(["compare", str(tmp_path / "A"), str(tmp_path / "nothing")]) == 2
    assert "no runs.jsonl" in capsys.readouterr().err
