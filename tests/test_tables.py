"""Tables and statistics: bootstrap against a closed form, paired tests by hand, identical inputs -> identical files."""

import numpy as np
import pandas as pd
import pytest
from scipy import stats as st

from harness.evaluation import stats, tables
from harness.evaluation.methods import CURVE_POINTS
from harness.evaluation.report import make_report
from harness.evaluation.runner import run_scenario
from harness.evaluation.loading import parse_scenario

from fakes import TINY, fake_run  # noqa: E402


def test_bootstrap_interval_matches_the_normal_interval_of_a_known_sample():
    x = np.random.default_rng(3).normal(10.0, 2.0, size=400)
    lo, hi = stats.bootstrap_ci(x, np.random.default_rng(0), n_boot=4000)
    half = st.norm.ppf(0.975) * x.std(ddof=1) / np.sqrt(len(x))
    assert lo == pytest.approx(x.mean() - half, abs=0.1 * half)
    assert hi == pytest.approx(x.mean() + half, abs=0.1 * half)
    assert stats.bootstrap_ci(np.array([2.5, np.nan]), np.random.default_rng(0)) == (2.5, 2.5)
    assert all(np.isnan(stats.bootstrap_ci(np.array([np.nan]), np.random.default_rng(0))))


def test_mcnemar_exact_by_hand():
    a = np.array([1, 1, 1, 1, 1, 0, 1, 0])
    b = np.array([0, 0, 0, 0, 0, 0, 1, 0])           # 5 discordant pairs, all in a's favour
    out = stats.mcnemar_exact(a, b)
    assert (out["a_only"], out["b_only"], out["n_pairs"]) == (5, 0, 8)
    assert out["p_value"] == pytest.approx(2 * 0.5**5)
    assert stats.mcnemar_exact(a, a)["p_value"] == 1.0


def test_wilcoxon_pairs_drop_nan_and_detect_a_shift():
    rng = np.random.default_rng(4)
    b = rng.normal(50, 5, size=30)
    a = b + 3.0 + rng.normal(0, 0.5, size=30)
    a[0] = np.nan
    out = stats.wilcoxon_paired(a, b)
    assert out["n_pairs"] == 29 and out["median_diff"] == pytest.approx(np.nanmedian(a - b))
    assert out["p_value"] < 1e-6                     # every difference positive: 2 / 2**29
    assert np.isnan(stats.wilcoxon_paired(b, b)["p_value"])


@pytest.fixture(scope="module")
def rows(tmp_path_factory):
    return run_scenario(parse_scenario(TINY), tmp_path_factory.mktemp("r") / "tiny", fake_run, progress=False)


def test_summary_cells_against_numpy(rows):
    summ = tables.summary(rows, ["markers.count", "occluders.amount"], n_boot=500)
    cond = rows["condition"].iloc[0]
    g = rows[(rows["condition"] == cond) & (rows["method"] == "full")]
    cell = summ[(summ["condition"] == cond) & (summ["method"] == "full") & (summ["metric"] == "mpjpe_cam_mm")]
    assert cell["n"].item() == len(g) == 6
    assert cell["mean"].item() == pytest.approx(g["mpjpe_cam_mm"].mean())
    assert cell["std"].item() == pytest.approx(g["mpjpe_cam_mm"].std(ddof=1))
    assert cell["ci_lo"].item() < cell["mean"].item() < cell["ci_hi"].item()
    ttc = summ[(summ["metric"] == "time_to_correct_s")]
    assert (ttc["n"] <= 6).all()                     # NaN (never correct) is left out of the mean
    assert list(dict.fromkeys(summ["method"])) == ["full", "gt_base", "no_database"]


def test_confusion_and_per_class_count_by_hand(rows):
    conf = tables.confusion(rows, ["walk", "run", "kick"])
    assert not [k for k in conf if k[1] == "no_database"]          # no recognition: no matrix, no class rows
    assert "no_database" not in set(tables.per_class(rows)["method"])
    g = rows[(rows["condition"] == rows["condition"].iloc[0]) & (rows["method"] == "full")]
    mat = conf[(rows["condition"].iloc[0], "full")]
    for t in ("walk", "run", "kick"):
        for p in ("walk", "run", "kick"):
            assert mat.loc[t, p] == int(((g["class_true"] == t) & (g["class_pred"] == p)).sum())
    pc = tables.per_class(rows)
    r = pc[(pc["condition"] == g["condition"].iloc[0]) & (pc["method"] == "full") & (pc["class_true"] == "walk")]
    assert r["accuracy"].item() == pytest.approx(g.loc[g["class_true"] == "walk", "correct"].mean())


def test_class_answers_and_right_out_of_runs_count_by_hand(rows):
    """``answers``: per answered class how often it answered, rightly and for which other classes' motions;
    ``class_accuracy``: right/runs per true class, one column per recognising method."""
    ans, acc = tables.answers(rows), tables.class_accuracy(rows)
    assert "no_database" not in set(ans["method"]) and "no_database" not in acc.columns
    for (cond, method), g in rows[rows["method"] != "no_database"].groupby(["condition", "method"]):
        mine = ans[(ans["condition"] == cond) & (ans["method"] == method)]
        assert mine["answered"].sum() == len(g) and list(mine["for_others"]) == sorted(mine["for_others"], reverse=True)
        for _, a in mine.iterrows():
            said = g[g["class_pred"] == a["answer"]]
            assert a["answered"] == len(said) and a["right"] == int((said["class_true"] == a["answer"]).sum())
            others = said[said["class_true"] != a["answer"]]["class_true"].value_counts()
            assert a["for_others"] == others.sum()
            assert sorted(a["from"].split(", ")) == sorted(f"{c} {n}" for c, n in others.items()) if len(others) else a["from"] == ""
        for t, gt in g.groupby("class_true"):
            cell = acc[(acc["condition"] == cond) & (acc["class_true"] == t)][method].item()
            assert cell == f"{int(gt['correct'].sum())}/{len(gt)}"


def test_paired_tests_pair_the_same_runs(rows):
    pt = tables.paired_tests(rows)
    cond = rows["condition"].iloc[0]
    mc = pt[(pt["condition"] == cond) & (pt["test"] == "McNemar (exact)")].iloc[0]
    f = rows[(rows["condition"] == cond) & (rows["method"] == "full")].set_index("run_key")["correct"]
    n = rows[(rows["condition"] == cond) & (rows["method"] == "gt_base")].set_index("run_key")["correct"]
    a_only, b_only = int(((f == 1) & (n == 0)).sum()), int(((f == 0) & (n == 1)).sum())
    assert mc["effect"] == f"full only right {a_only}, gt_base only right {b_only}"
    assert mc["n_pairs"] == 6
    assert not ((pt["comparison"] == "full vs no_database") & (pt["test"] == "McNemar (exact)")).any()


def test_same_scenario_twice_gives_identical_tables_and_report(tmp_path):
    scenario = parse_scenario(TINY)
    texts = []
    for d in ("a", "b"):
        out = tmp_path / d
        rows = run_scenario(scenario, out, fake_run, progress=False)
        rows["ms_per_frame"] = 10.0 if d == "a" else 99.0     # timing differs between machines and runs
        make_report(scenario, out, rows, plots=False)
        report = (out / "report.md").read_text().split("## Timing")[0].replace(str(out), "DIR")
        texts.append([report] + [(out / f"{n}.csv").read_text() for n in
                                 ("headline", "per_class", "confusion", "paired_tests")])
    assert texts[0] == texts[1]
    assert "## Headline" in texts[0][0] and "McNemar" in texts[0][0]
    summ = [pd.read_csv(tmp_path / d / "summary.csv") for d in ("a", "b")]
    keep = [s[s["metric"] != "ms_per_frame"].reset_index(drop=True) for s in summ]
    pd.testing.assert_frame_equal(keep[0], keep[1])


def test_pooled_metrics_are_means_over_runs(rows):
    pooled = tables.pooled_metrics(rows)
    full = rows[rows["method"] == "full"]
    assert pooled["full/correct"] == pytest.approx(full["correct"].mean())
    assert pooled["no_database/mpjpe_cam_mm"] == pytest.approx(rows.loc[rows["method"] == "no_database",
                                                                        "mpjpe_cam_mm"].mean())
    assert "full/n_frames" not in pooled


def test_headline_says_given_and_dash_and_rounds_to_three_figures(rows):
    summ = tables.summary(rows, ["markers.count", "occluders.amount"], n_boot=200)
    head = tables.headline(summ, ["markers.count", "occluders.amount"])
    nd = head[head["method"] == "no_database"].iloc[0]
    gb = head[head["method"] == "gt_base"].iloc[0]
    full = head[head["method"] == "full"].iloc[0]
    assert nd["correct"] == "–" and nd["log_p_true"] == "–" and nd["base_pos_err_m"] == "given"
    assert gb["heading_err_deg"] == "given" and gb["correct"] != "–"
    assert full["base_pos_err_m"] not in ("given", "–") and nd["runs"] == 6
    timing = tables.headline(summ, ["markers.count", "occluders.amount"], tables.TIMING)
    assert (timing["runs"] == head["runs"]).all() and nd["runs"] == 6
    assert tables._fmt(0.0004331) == "0.000433" and tables._fmt(1.189e-15) == "1.19e-15" and tables._fmt(103.4) == "103"


def test_accuracy_over_time_is_the_mean_of_the_stored_curves(rows):
    curve = tables.accuracy_over_time(rows)
    assert set(curve["method"]) == {"full", "gt_base"}
    cond = rows["condition"].iloc[0]
    g = rows[(rows["condition"] == cond) & (rows["method"] == "full")]
    by_hand = np.mean([c[4] for c in g["accuracy_curve"]])
    cell = curve[(curve["condition"] == cond) & (curve["method"] == "full")].iloc[4]
    assert cell["accuracy"] == pytest.approx(by_hand) and cell["fraction"] == pytest.approx(4 / 9, abs=1e-3)


def test_worst_runs_are_wrong_first_then_least_sure(rows):
    worst = tables.worst_runs(rows, "full", 3)
    full = rows[rows["method"] == "full"]
    wrong = full[full["correct"] == 0].sort_values("log_p_true")
    right = full[full["correct"] == 1].sort_values("log_p_true")
    assert 0 < len(wrong) < 3
    assert list(worst["run_key"]) == (list(wrong["run_key"]) + list(right["run_key"]))[:3]


def test_a_report_without_recognition_has_no_recognition_sections(rows, tmp_path):
    """A scenario whose methods do not recognise (reproduction alone, or here no_database) gets no empty
    recognition, confusion or paired-test sections; the full rows get all three."""
    scenario = parse_scenario(TINY)
    alone = make_report(scenario, tmp_path / "alone", rows[rows["method"] == "no_database"], plots=False).read_text()
    whole = make_report(scenario, tmp_path / "whole", rows, plots=False).read_text()
    for section in ("## Recognition against time", "## Recognition per class", "## Confusion matrices",
                    "## Paired tests", "## Calibration of the final class posterior"):
        assert section not in alone and section in whole
    assert "## Headline" in alone and "no_database" in alone


def test_recognition_and_heading_by_viewing_direction(tmp_path):
    """by_view bins the runs by |view_azimuth_deg| (front < 45, side, back >= 135) and pools conditions; a
    method's given columns are left out; the report draws it."""
    rows = run_scenario(parse_scenario(TINY), tmp_path / "tiny", fake_run, progress=False)
    keys = sorted(rows["run_key"].unique())
    azimuth = {k: [10.0, -60.0, 170.0, 100.0][i % 4] for i, k in enumerate(keys)}
    rows = rows.assign(view_azimuth_deg=rows["run_key"].map(azimuth),
                       heading_err_deg=rows["base_rot_err_deg"], heading_err_twin_deg=rows["base_rot_err_deg"] / 2)
    table = tables.by_view(rows, n_boot=200)
    full = table[(table["method"] == "full") & (table["metric"] == "correct")].set_index("view")
    for view, azimuths in (("front", {10.0}), ("side", {-60.0, 100.0}), ("back", {170.0})):
        g = rows[(rows["method"] == "full") & rows["view_azimuth_deg"].isin(azimuths)]
        assert full.loc[view, "n"] == len(g) and full.loc[view, "mean"] == pytest.approx(g["correct"].mean())
    assert not ((table["method"] == "gt_base") & table["metric"].str.startswith("heading")).any()   # given
    assert set(table[table["method"] == "no_database"]["metric"]) == set()   # recognises nothing, given heading
    assert tables.by_view(rows.drop(columns="view_azimuth_deg")).empty
    make_report(parse_scenario(TINY), tmp_path / "tiny", rows)
    assert (tmp_path / "tiny" / "plots" / "by_view.png").is_file()
    assert "## Against the viewpoint" in (tmp_path / "tiny" / "report.md").read_text()
    assert (tmp_path / "tiny" / "by_view.csv").is_file()


def test_heading_over_time_is_the_median_of_the_stored_curves(rows):
    rng = np.random.default_rng(3)
    rows = rows.assign(heading_curve=[list(rng.uniform(0, 180, CURVE_POINTS)) if m != "gt_base" else []
                                      for m in rows["method"]])
    curve = tables.heading_over_time(rows)
    assert set(curve["method"]) == {"full", "no_database"}          # gt_base is given the pose: no curve
    cond = rows["condition"].iloc[0]
    g = rows[(rows["condition"] == cond) & (rows["method"] == "full")]
    cell = curve[(curve["condition"] == cond) & (curve["method"] == "full")].iloc[3]
    assert cell["heading_err_median_deg"] == pytest.approx(np.median([c[3] for c in g["heading_curve"]]))
    assert cell["q25"] <= cell["heading_err_median_deg"] <= cell["q75"] and cell["runs"] == len(g)


def test_open_set_rows_are_in_no_accuracy_but_their_own_table(tmp_path):
    """Two known runs (one right) and an open-set run answered walk with 0.9: the headline's accuracy is 1/2
    over the two known runs, the open-set table has the third with its answer and confidence, and a second test
    set splits every condition by set."""
    post = {"walk": 0.9, "kick": 0.1}
    runs = pd.DataFrame({"run_key": ["a", "b", "c"], "condition": "base", "method": "joint_space",
                         "source": ["cmu", "bandai", "bandai"], "style": ["", "tired", "tired"],
                         "class_true": ["walk", "kick", "other"], "class_pred": ["walk", "walk", "walk"],
                         "correct": [1, 0, float("nan")], "open_set": [False, False, True],
                         "confidence": [0.8, 0.6, 0.9], "posterior_final": [post, post, post],
                         "frame_accuracy": [1.0, 0.0, float("nan")], "time_to_correct_s": [0.1, float("nan"),
                                                                                          float("nan")],
                         "log_p_true": [-0.2, -2.3, float("nan")], "accuracy_curve": [[1] * 10, [0] * 10, []],
                         "n_frames": 30, "ms_per_frame": 1.0})
    out = tables.write_tables(runs, tmp_path, [], ["walk", "kick"], n_boot=50)
    assert list(out["headline"]["condition"]) == ["base / bandai", "base / cmu"] or \
        list(out["headline"]["condition"]) == ["base / cmu", "base / bandai"]
    assert out["open_set"].iloc[0][["class_true", "runs", "answers", "confidence"]].tolist() == [
        "other", 1, "walk 1", 0.9]
    assert out["by_source"].set_index("source")["right"].to_dict() == {"cmu": 1, "bandai": 0}
    assert out["by_style"].set_index("style")["runs"].to_dict() == {"": 1, "tired": 1}
    assert tables.pooled_metrics(tables.known_and_open_set(runs)[0])["joint_space/correct"] == 0.5


def test_heading_spread_against_a_built_case(tmp_path):
    """Mean, median, the share within 20 deg and the share settled on the twin by hand; the mean over the other
    runs leaves the twins out; given-pose methods are left out; the table is written, the report shows it and
    the plot is drawn, and neither is made without the heading columns."""
    from harness.evaluation.plots import plot_heading_spread

    rows = run_scenario(parse_scenario(TINY), tmp_path / "tiny", fake_run, progress=False)
    rng = np.random.default_rng(12)
    heading = rng.uniform(0.0, 180.0, len(rows))
    # Up to the twin, a run beyond 135 deg is within 45 deg; one at 90-135 deg is a quarter turn, not the twin.
    twin = np.where(heading > 135.0, 180.0 - heading, np.minimum(heading, 60.0))
    rows = rows.assign(heading_err_deg=heading, heading_err_twin_deg=twin)
    table = tables.heading_spread(rows)
    assert set(table["method"]) == {"full"}                  # gt_base and no_database are handed the pose
    for _, cell in table.iterrows():
        g = rows[(rows["condition"] == cell["condition"]) & (rows["method"] == "full")]
        h = g["heading_err_deg"].to_numpy()
        assert cell["n"] == len(g)
        assert cell["heading_mean"] == pytest.approx(h.mean()) and cell["heading_median"] == pytest.approx(np.median(h))
        assert cell["within_20"] == pytest.approx(np.mean(h <= 20.0))
        assert cell["on_twin"] == pytest.approx(np.mean(h > 135.0))
        if (h <= 135.0).any():
            assert cell["heading_mean_not_twin"] == pytest.approx(h[h <= 135.0].mean())
    assert (table["on_twin"] > 0).any() and (table["on_twin"] < 1).any()
    assert tables.heading_spread(rows.drop(columns="heading_err_twin_deg")).empty
    tables.write_tables(rows, tmp_path / "out", ["markers.count", "occluders.amount"], [], n_boot=50)
    assert len(pd.read_csv(tmp_path / "out" / "heading_spread.csv")) == len(table)
    make_report(parse_scenario(TINY), tmp_path / "tiny", rows, plots=False)
    assert "## How the heading errors spread" in (tmp_path / "tiny" / "report.md").read_text()
    assert plot_heading_spread(rows, tmp_path / "spread.png") and (tmp_path / "spread.png").stat().st_size > 0
    assert not plot_heading_spread(rows.drop(columns="heading_err_deg"), tmp_path / "none.png")


def test_pose_error_split_against_a_built_case(tmp_path):
    """A camera-frame error made of the rotation alone correlates 1 with it and not with a depth error drawn
    apart; the near and far runs are those within 20 deg and beyond 45 deg; given-pose methods are left out;
    the table is written with the others."""
    rows = run_scenario(parse_scenario(TINY), tmp_path / "tiny", fake_run, progress=False)
    rng = np.random.default_rng(11)
    heading = rng.uniform(0.0, 180.0, len(rows))
    rows = rows.assign(heading_err_deg=heading, base_rot_err_deg=heading + 5.0,
                       base_depth_err_m=rng.uniform(0.0, 1.0, len(rows)),
                       mpjpe_cam_mm=100.0 + 2.0 * heading, mpjpe_pose_mm=100.0)
    table = tables.pose_error_split(rows)
    assert set(table["method"]) == {"full"}                  # gt_base and no_database are handed the pose
    cond = rows["condition"].iloc[0]
    g = rows[(rows["condition"] == cond) & (rows["method"] == "full")]
    cell = table[(table["condition"] == cond) & (table["method"] == "full")].iloc[0]
    near, far = g[g["heading_err_deg"] <= 20.0], g[g["heading_err_deg"] > 45.0]
    assert cell["n"] == len(g) and cell["corr_rotation"] == pytest.approx(1.0)
    assert abs(cell["corr_depth"]) == pytest.approx(abs(np.corrcoef(g["mpjpe_cam_mm"], g["base_depth_err_m"])[0, 1]))
    assert cell["n_near"] == len(near) and cell["n_far"] == len(far)
    assert table["n_near"].sum() > 0 and table["n_far"].sum() > 0
    both = table[(table["n_near"] > 0)].iloc[0]
    g = rows[(rows["condition"] == both["condition"]) & (rows["method"] == "full")]
    assert both["mpjpe_cam_near"] == pytest.approx(g[g["heading_err_deg"] <= 20.0]["mpjpe_cam_mm"].mean())
    assert cell["mpjpe_cam_far"] == pytest.approx(100.0 + 2.0 * far["heading_err_deg"].mean())
    assert cell["mpjpe_cam_mm"] == pytest.approx(g["mpjpe_cam_mm"].mean())
    assert tables.pose_error_split(rows.drop(columns="heading_err_deg")).empty
    tables.write_tables(rows, tmp_path / "out", ["markers.count", "occluders.amount"], [], n_boot=50)
    written = pd.read_csv(tmp_path / "out" / "pose_error_split.csv")
    assert len(written) == len(table)
    make_report(parse_scenario(TINY), tmp_path / "tiny", rows, plots=False)
    assert "## What the camera-frame error is made of" in (tmp_path / "tiny" / "report.md").read_text()
