"""Calibration of the final class posterior (harness.evaluation.calibration): every metric on small cases
computed by hand, the edge cases (all right, a tie, a zero probability of the true class, fewer runs than bins,
tied confidences across a bin edge), the runner's table, and the real pipeline's rows."""

import json

import numpy as np
import pandas as pd
import pytest

from harness.evaluation import calibration as cal
from harness.evaluation.metrics import MetricError

LN_FLOOR = -np.log(1e-15)       # 34.538776...: the documented cost of a zero probability of the true class


def _all(probs, true, n_bins=cal.ECE_BINS) -> dict:
    return cal.scores(np.array(probs, dtype=float), np.array(true), n_bins)


def test_all_right_and_certain_scores_zero():
    s = _all([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]], [0, 1])
    assert (s["ece"], s["brier"], s["nll"], s["confident_wrong"]) == (0.0, 0.0, 0.0, 0.0)
    assert (s["runs"], s["accuracy"], s["wrong"], s["bins"]) == (2, 1.0, 0, 1)     # both at 1.0: one tie, one bin


def test_all_right_but_unsure():
    # Four runs at 0.8 on the true class: right every time, 0.2 less sure than it could be.
    s = _all([[0.8, 0.2]] * 4, [0] * 4)
    assert s["ece"] == pytest.approx(0.2)
    assert s["brier"] == pytest.approx(0.2**2 + 0.2**2)            # 0.08
    assert s["nll"] == pytest.approx(-np.log(0.8))                   # 0.2231 nats
    assert s["confident_wrong"] == 0.0 and s["confidence"] == pytest.approx(0.8)


def test_a_tie_in_the_posterior_answers_the_first_class():
    # (0.5, 0.5, 0) with the second class true: the answer is the first (as class_pred's argmax), so wrong.
    s = _all([[0.5, 0.5, 0.0]], [1])
    assert s["accuracy"] == 0.0 and s["confidence"] == 0.5
    assert s["ece"] == pytest.approx(0.5)
    assert s["brier"] == pytest.approx(0.25 + 0.25 + 0.0)
    assert s["nll"] == pytest.approx(np.log(2.0))
    assert s["wrong"] == 1 and s["confident_wrong"] == 0.0          # wrong, but not above 0.99


def test_a_zero_probability_of_the_true_class_costs_the_floor():
    s = _all([[1.0, 0.0]], [1])
    assert s["nll"] == pytest.approx(34.538776, abs=1e-6) == LN_FLOOR
    assert s["brier"] == pytest.approx(2.0) and s["ece"] == pytest.approx(1.0) and s["confident_wrong"] == 1.0


def test_fewer_runs_than_bins_puts_each_run_in_its_own_bin():
    # a: tie 0.5/0.5, true second -> wrong at 0.5; b: certain of the wrong class; c: right at 0.7.
    probs = [[0.5, 0.5, 0.0], [1.0, 0.0, 0.0], [0.2, 0.7, 0.1]]
    s = _all(probs, [1, 1, 1])
    assert s["bins"] == 3
    assert s["ece"] == pytest.approx((0.5 + 1.0 + 0.3) / 3)                        # 0.6
    assert s["brier"] == pytest.approx((0.5 + 2.0 + (0.04 + 0.09 + 0.01)) / 3)     # 0.88
    assert s["nll"] == pytest.approx((np.log(2) + LN_FLOOR - np.log(0.7)) / 3)      # 11.8629
    assert s["wrong"] == 2 and s["confident_wrong"] == pytest.approx(0.5)         # b of a and b


def test_equal_mass_bins_by_hand():
    # Ten runs, five bins of two: |acc - conf| per bin .075, .175, .225, .375, .025, each weighing 2/10.
    conf = np.array([0.55, 0.60, 0.65, 0.70, 0.75, 0.80, 0.85, 0.90, 0.95, 1.00])
    right = np.array([0, 1, 0, 1, 1, 1, 0, 1, 1, 1], dtype=bool)
    assert cal.ece(conf, right, 5) == pytest.approx(0.175)
    rel = cal.reliability(conf, right, 5)
    assert list(rel["runs"]) == [2] * 5 and rel["accuracy"].tolist() == [0.5, 0.5, 1.0, 0.5, 1.0]
    assert rel["confidence"].tolist() == pytest.approx([0.575, 0.675, 0.775, 0.875, 0.975])
    assert rel["conf_lo"].tolist() == [0.55, 0.65, 0.75, 0.85, 0.95]
    # 25 distinct confidences in 10 bins: floor(10 r / 25) gives counts 3, 2, 3, 2, ...
    assert np.bincount(cal.equal_mass_bins(np.linspace(0, 1, 25)[::-1], 10)).tolist() == [3, 2] * 5
    # One bin is the gap between mean accuracy and mean confidence.
    assert cal.ece(conf, right, 1) == pytest.approx(abs(right.mean() - conf.mean()))


def test_a_tie_is_never_split_between_bins():
    # Ranks of the first of each tie: 0, 1, 1, 1, 4, 4 -> bins floor(3 r / 6) = 0, 0, 0, 0, 2, 2: two bins.
    conf = np.array([0.6, 0.7, 0.7, 0.7, 0.9, 0.9])
    right = np.array([1, 0, 1, 1, 1, 0], dtype=bool)
    assert cal.equal_mass_bins(conf, 3).tolist() == [0, 0, 0, 0, 1, 1]
    by_hand = 4 / 6 * abs(0.75 - 0.675) + 2 / 6 * abs(0.5 - 0.9)       # 0.18333
    assert cal.ece(conf, right, 3) == pytest.approx(by_hand)
    # The order of the rows does not matter (it would if the tie at 0.7 were cut by position).
    rng = np.random.default_rng(0)
    for _ in range(10):
        p = rng.permutation(6)
        assert cal.ece(conf[p], right[p], 3) == pytest.approx(by_hand)
    # Everything certain (the engine's usual case): one bin, ECE = 1 - accuracy.
    assert cal.ece(np.ones(5), np.array([1, 1, 1, 0, 0], dtype=bool)) == pytest.approx(0.4)


def test_bad_posteriors_are_refused():
    with pytest.raises(MetricError, match="summing to one"):
        cal.brier(np.array([[0.5, 0.2]]), np.array([0]))
    with pytest.raises(MetricError, match=r"\(N, C\)"):
        cal.nll(np.array([0.5, 0.5]), np.array([0]))
    with pytest.raises(MetricError, match="n_bins"):
        cal.equal_mass_bins(np.array([0.5]), 0)


def _rows() -> pd.DataFrame:
    # Condition A: the three runs of test_fewer_runs_than_bins; condition B: one right at 0.8 (read back from
    # runs.csv as a string); a method without recognition has no posterior and is left out.
    post = [{"x": 0.5, "y": 0.5, "z": 0.0}, {"x": 1.0, "y": 0.0, "z": 0.0}, {"x": 0.2, "y": 0.7, "z": 0.1},
            repr({"x": 0.8, "y": 0.1, "z": 0.1}), {}]
    return pd.DataFrame({"condition": ["A", "A", "A", "B", "A"], "amount": [0.0, 0.0, 0.0, 0.4, 0.0],
                         "method": ["full", "full", "full", "full", "no_database"],
                         "class_true": ["y", "y", "y", "x", "y"], "posterior_final": post})


def test_the_table_per_condition_and_pooled():
    table = cal.calibration_table(_rows(), ["amount"]).set_index(["condition", "method"])
    assert list(table.index) == [("A", "full"), ("B", "full"), ("all conditions", "full")]
    a, b, pooled = table.loc[("A", "full")], table.loc[("B", "full")], table.loc[("all conditions", "full")]
    assert a["ece"] == pytest.approx(0.6) and a["brier"] == pytest.approx(0.88) and a["runs"] == 3
    assert b["ece"] == pytest.approx(0.2) and b["brier"] == pytest.approx(0.2**2 + 0.1**2 + 0.1**2)
    assert b["amount"] == 0.4 and pooled["amount"] == ""
    # Pooled: four runs in four bins, conf .5 (wrong), .7 (right), .8 (right), 1 (wrong).
    assert pooled["ece"] == pytest.approx((0.5 + 0.3 + 0.2 + 1.0) / 4)
    assert pooled["nll"] == pytest.approx((np.log(2) + LN_FLOOR - np.log(0.7) - np.log(0.8)) / 4)
    assert pooled["accuracy"] == 0.5 and pooled["wrong"] == 2 and pooled["confident_wrong"] == 0.5
    assert cal.pooled_calibration(_rows()) == {f"full/{m}": pytest.approx(pooled[m]) for m in cal.METRICS}
    rel = cal.reliability_table(_rows())
    assert rel["runs"].tolist() == [1, 1, 1, 1] and rel["accuracy"].tolist() == [0.0, 1.0, 1.0, 0.0]
    rows = _rows()
    rows.loc[0, "class_true"] = "w"
    with pytest.raises(MetricError, match="'w'"):
        cal.calibration_table(rows)


def test_stored_rows_agree_with_the_other_recognition_columns(tmp_path):
    """The tables' rows (fake pipeline) through metrics.json: NLL is minus the mean log_p_true, accuracy the
    mean of correct, and the calibration table is written beside the others."""
    from fakes import TINY, fake_run
    from harness.evaluation.runner import run_scenario
    from harness.evaluation.loading import parse_scenario
    from harness.evaluation.tables import write_tables

    rows = run_scenario(parse_scenario(TINY), tmp_path / "tiny", fake_run, progress=False)
    write_tables(rows, tmp_path / "tiny", ["markers.count", "occluders.amount"], ["walk", "run", "kick"], n_boot=50)
    pooled = json.loads((tmp_path / "tiny" / "metrics.json").read_text())
    for method in ("full", "gt_base"):
        g = rows[rows["method"] == method]
        assert pooled[f"{method}/nll"] == pytest.approx(-g["log_p_true"].mean())
        assert pooled[f"{method}/brier"] > 0 and 0 < pooled[f"{method}/ece"] < 1
    assert "no_database/ece" not in pooled
    table = pd.read_csv(tmp_path / "tiny" / "calibration.csv")
    full = table[table["method"] == "full"]
    assert len(full) == 4 + 1                   # four conditions and all of them
    by_cond = rows[rows["method"] == "full"].groupby("condition", sort=False)["correct"].mean()
    assert full["accuracy"].iloc[:4].tolist() == pytest.approx(by_cond.tolist())


def test_the_pipeline_stores_the_posterior_that_decides(tmp_path):
    """One real run: every recognising method's posterior_final is the last frame's posterior (its argmax is
    class_pred, its maximum the confidence, its true-class entry exp(log_p_true)), and methods that do not
    recognise store none."""
    from harness.evaluation import pipeline, runner
    from harness.evaluation.loading import parse_scenario

    scenario = parse_scenario(
        {
            "name": "cal",
            "seed": 3,
            "test": {"demos_per_class": 1},
            "database": {"classes": ["walk", "squat", "kick"], "train_demos": 2, "states": 4},
            "markers": {"count": 30},
            "engine": {"tracks": {"particles": 30}, "model": {"points": 30}},
        }
    )
    run = runner.plan(scenario, tmp_path)[0]
    rows = pd.DataFrame([run.identity() | r for r in pipeline.run_one(run)])
    rec = rows[~rows["method"].isin(["no_database", "bottom_up"])]
    assert set(rec["method"]) == {"full", "full_smoothed", "gt_base", "joint_space"}
    for r in rec.itertuples(index=False):
        post = r.posterior_final
        assert sorted(post) == ["kick", "squat", "walk"] and sum(post.values()) == pytest.approx(1.0)
        assert max(post, key=post.get) == r.class_pred and r.confidence == max(post.values())
        assert r.log_p_true == pytest.approx(np.log(max(post[r.class_true], 1e-15)))
    assert rows.loc[rows["method"] == "no_database", "posterior_final"].item() == {}
    table = cal.calibration_table(rows).set_index("method")
    assert table.loc[rec["method"], "nll"].tolist() == pytest.approx((-rec["log_p_true"]).tolist())
    assert table.loc[rec["method"], "accuracy"].tolist() == rec["correct"].tolist()
