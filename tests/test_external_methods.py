"""Methods from outside the package: named module:function or installed under an entry point, their failures kept
to their own rows, their code's version stamped so that changed code is never mixed with old rows."""

import json
import textwrap
from dataclasses import replace

import pandas as pd
import pytest

from harness.cli import main
from harness.evaluation import external, pipeline, runner
from harness.evaluation.journal import ResultsError
from harness.evaluation.loading import parse_scenario
from harness.evaluation.scenario import ScenarioError, scenario_hash

SMALL = {"name": "outside", "seed": 4, "database": {"classes": ["walk", "kick"], "train_demos": 2, "states": 4},
         "test": {"demos_per_class": 2}, "markers": {"count": 30}}


@pytest.fixture(autouse=True)
def _forget():
    external.forget()
    yield
    external.forget()


def _evaluate(tmp_path, methods) -> tuple[int, pd.DataFrame]:
    scenario = tmp_path / "outside.yaml"
    scenario.write_text(json.dumps({**SMALL, "methods": methods}))
    code = main(["evaluate", str(scenario), "--results", str(tmp_path / "results"), "--quiet"])
    return code, pd.read_csv(tmp_path / "results" / "outside" / "runs.csv", keep_default_na=False)


def test_a_module_function_method_is_scored_under_the_name_as_written(tmp_path):
    code, rows = _evaluate(tmp_path, ["joint_space", "outside_methods:uniform"])
    assert code == 0
    mine = rows[rows["method"] == "outside_methods:uniform"]
    assert len(mine) == 4 and set(rows["method"]) == {"joint_space", "outside_methods:uniform"}
    # a uniform posterior answers the first of inputs.classes (the database's, sorted): right on the kicks only
    assert (mine["class_pred"] == "kick").all()
    assert list(mine["correct"].astype(float)) == [int(c == "kick") for c in mine["class_true"]]
    assert (mine["confidence"].astype(float) == 0.5).all()
    assert (mine["mpjpe_cam_mm"] == "").all()              # it does not recover: the columns stay empty
    assert (mine["method_version"] == external.source_version("outside_methods")).all()
    assert (mine["failed"] == "").all()
    report = (tmp_path / "results" / "outside" / "report.md").read_text()
    assert "outside_methods:uniform" in report and "Failed rows" not in report


def test_a_method_that_raises_fails_its_own_rows_and_the_evaluation_goes_on(tmp_path, capsys):
    code, rows = _evaluate(tmp_path, ["joint_space", "outside_methods:fails_on_kick"])
    assert code == 0
    mine = rows[rows["method"] == "outside_methods:fails_on_kick"].set_index("class_true")
    assert (mine.loc["kick", "failed"] == "ValueError: no kick here").all()
    assert (mine.loc["kick", "correct"] == "").all()
    assert (mine.loc["walk", "failed"] == "").all() and (mine.loc["walk", "correct"].astype(float) == 0).all()
    others = rows[rows["method"] == "joint_space"]
    assert len(others) == 4 and (others["correct"] != "").all()       # every other row complete
    report = (tmp_path / "results" / "outside" / "report.md").read_text()
    section = report.split("## Failed rows")[1].split("\n## ")[0]
    assert "2 of 8 rows failed" in section
    assert section.count("ValueError: no kick here") == 2 and "c000/r000/kick/d002" in section
    assert "2 rows failed (method outside_methods:fails_on_kick)" in capsys.readouterr().err


def test_an_estimate_that_breaks_the_protocol_fails_its_row_naming_what_is_wrong(tmp_path):
    code, rows = _evaluate(tmp_path, ["outside_methods:wrong_shape"])
    assert code == 0
    assert set(rows["failed"]) == {"MethodError: method 'outside_methods:wrong_shape' recognises: class_posterior "
                                   "must be (%d, 2) (frames x classes), got (%d, 3)" % (n, n)
                                   for n in rows["n_frames"].astype(int)}


@pytest.mark.parametrize("name, message", [
    ("nomodule_here:f", "method 'nomodule_here:f': cannot import module 'nomodule_here' (ModuleNotFoundError: No "
                        "module named 'nomodule_here')"),
    ("outside_methods:nope", "method 'outside_methods:nope': module 'outside_methods' has no 'nope'"),
    ("outside_methods:not_callable", "outside_methods.not_callable is not callable (got int)"),
    ("outside_methods:undeclared", "not declared; decorate the function with "
                                   "@harness.evaluation.methods.declare(recognises=..., recovers=...)"),
    ("outside_methods:future", "declares protocol 99; this harness runs protocol 1"),
    ("not a:name", "write an outside method as module.path:function"),
    ("fulll", "unknown method 'fulll' (built in: full, full_smoothed,"),
])
def test_a_method_that_cannot_be_used_is_refused_at_load_naming_it(name, message):
    with pytest.raises(ScenarioError) as err:
        parse_scenario({**SMALL, "methods": ["full", name]}, "s.yaml")
    assert str(err.value).startswith("s.yaml: methods[1]: ")
    assert message in str(err.value)


def test_the_command_line_refuses_an_unimportable_method_in_one_line_and_writes_nothing(tmp_path, capsys):
    scenario = tmp_path / "s.yaml"
    scenario.write_text(json.dumps({**SMALL, "methods": ["nomodule_here:estimate"]}))
    assert main(["evaluate", str(scenario), "--results", str(tmp_path / "results")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "cannot import module 'nomodule_here'" in err
    assert not (tmp_path / "results").exists()


def _package(root, body: str) -> None:
    (root / "mymeth").mkdir(parents=True, exist_ok=True)
    (root / "mymeth" / "__init__.py").write_text(textwrap.dedent(body))


_MY_METHOD = """
    import numpy as np
    from harness.engine import Estimate
    from harness.evaluation.methods import declare

    @declare(recognises=True, recovers=False)
    def estimate(inputs, engine):
        n, c = len(inputs.obs), len(inputs.classes)
        post = np.zeros((n, c))
        post[:, {answer}] = 1.0      # 0: kick, 1: walk (the database's classes, sorted)
        return Estimate(np.asarray(inputs.classes), class_posterior=post)
"""


def test_changed_method_code_is_never_mixed_with_old_rows(tmp_path, monkeypatch):
    """An edit of the method's package changes its version, hence the scenario hash: the old journal is refused
    (--fresh sets it aside), and a worker running other code than the run was planned with refuses the run."""
    monkeypatch.syspath_prepend(str(tmp_path / "pkgs"))
    _package(tmp_path / "pkgs", _MY_METHOD.format(answer=0))
    before = parse_scenario({**SMALL, "methods": ["mymeth:estimate"]})
    results = tmp_path / "results" / "outside"
    table = runner.run_scenario(before, results, pipeline.run_one, limit=1, progress=False)
    assert table["method_version"].tolist() == [before.method_versions["mymeth:estimate"]]
    _package(tmp_path / "pkgs", _MY_METHOD.format(answer=1))
    run = runner.plan(before, tmp_path / "results" / "cache")[1]
    external.forget()                                    # a new process, or a worker started after the edit
    with pytest.raises(runner.RunError, match="method 'mymeth:estimate' is version .* the run was planned with"):
        pipeline.run_one(run)
    after = parse_scenario({**SMALL, "methods": ["mymeth:estimate"]})
    assert after.method_versions != before.method_versions
    assert scenario_hash(after) != scenario_hash(before)
    with pytest.raises(ResultsError, match="pass --fresh"):
        runner.run_scenario(after, results, pipeline.run_one, progress=False)
    table = runner.run_scenario(after, results, pipeline.run_one, fresh=True, progress=False)
    assert set(table["method_version"]) == {after.method_versions["mymeth:estimate"]}
    assert set(table["class_pred"]) == {"walk"}
    assert pipeline.run_one(replace(run, config=after))[0]["class_pred"] == "walk"


def test_an_installed_method_is_found_by_its_entry_point_name(tmp_path, monkeypatch):
    """A distribution on the path (its metadata and entry points as pip installs them) registers a method under
    the group harness.methods; its version is the distribution's and its code's."""
    site = tmp_path / "site"
    _package(site, _MY_METHOD.format(answer=1))
    info = site / "mymeth-2.5.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: mymeth\nVersion: 2.5\n")
    (info / "entry_points.txt").write_text("[harness.methods]\nalways_walk = mymeth:estimate\n")
    (info / "RECORD").write_text("mymeth/__init__.py,,\n")
    (info / "top_level.txt").write_text("mymeth\n")
    monkeypatch.syspath_prepend(str(site))
    external.forget()
    assert "always_walk" in external.entry_points()
    scenario = parse_scenario({**SMALL, "methods": ["joint_space", "always_walk"]})
    version = scenario.method_versions["always_walk"]
    assert version.startswith("2.5+") and version == external.source_version("mymeth")
    run = runner.plan(scenario, tmp_path / "cache")[0]
    rows = {r["method"]: r for r in pipeline.run_one(run)}
    assert rows["always_walk"]["class_pred"] == "walk" and rows["always_walk"]["method_version"] == version
    assert "method_version" not in rows["joint_space"]     # built-in rows: the package's version is in the hash


def test_method_versions_are_always_those_of_the_code():
    """A stored scenario (scenario.json, read again by run-video) carries the stamps of when it was stored; loaded,
    they are the code's now, whatever was written."""
    stamped = parse_scenario({**SMALL, "methods": ["outside_methods:uniform"], "method_versions": {"x:y": "1"}})
    assert stamped.method_versions == {"outside_methods:uniform": external.source_version("outside_methods")}
    assert parse_scenario({**SMALL, "method_versions": {"x:y": "1"}}).method_versions == {}
    with pytest.raises(ScenarioError, match="not sweepable"):
        parse_scenario({**SMALL, "sweep": {"method_versions": [{}]}}, "s.yaml")
