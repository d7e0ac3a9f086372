"""``results/<scenario>/report.md``: the scenario, the headline table, per-class recognition, paired tests,
confusion matrices and plots in one date-free document (identical rows give an identical report except the
timing section, which is reported but is not part of any identity check)."""

from __future__ import annotations

import math
from pathlib import Path

import pandas as pd
import yaml

from harness.evaluation.calibration import CONFIDENT, ECE_BINS, NLL_FLOOR
from harness.evaluation.plots import write_plots
from harness.evaluation.runner import load_rows
from harness.evaluation.scenario import Scenario, scenario_hash
from harness.evaluation.tables import by_test_set, is_stream, known_and_open_set, markdown, recognising, write_tables
from harness.io import write_text_atomic


def swept_keys(scenario: Scenario) -> list[str]:
    return list(scenario.sweep)


def classes_of(scenario: Scenario, rows: pd.DataFrame) -> list[str]:
    """The class order of tables and plots: the scenario's classes, then any other label seen in the rows."""
    listed = list(scenario.classes)
    seen = sorted(set(rows.get("class_true", [])) - set(listed)) if len(rows) else []
    return listed + seen


def _section_plots(figures: list[str], names: tuple[str, ...]) -> list[str]:
    return [f"![{Path(f).stem}]({f})\n" for f in figures if Path(f).stem in names]


def make_report(scenario: Scenario, results_dir: str | Path, rows: pd.DataFrame | None = None,
                plots: bool = True) -> Path:
    """Write every table, plot and ``report.md`` of a scenario's results directory; return the report path.

    The report opens with the headline table; then recognition against time, per class (heat map), the
    calibration of the final class posterior (table and reliability diagrams), the three worst runs of ``full``
    with the command that renders each, paired tests, confusion matrices of the methods that recognise, plots
    against the swept keys, the scenario, and timing last."""
    results_dir = Path(results_dir)
    digest = scenario_hash(scenario)
    rows = load_rows(results_dir, digest) if rows is None else rows
    swept, classes = swept_keys(scenario), classes_of(scenario, rows)
    if not len(rows):
        others = load_rows(results_dir)
        hint = (f" The journal holds {others['run_key'].nunique()} runs under other hashes (another version of the "
                f"scenario or of the code): run `harness evaluate` with --fresh.") if len(others) else ""
        text = f"# {scenario.name}\n\nNo finished runs under scenario hash `{digest}`.{hint}\n"
        path = results_dir / "report.md"
        write_text_atomic(path, text)
        return path
    tables = write_tables(rows, results_dir, swept, classes, seed=scenario.seed)
    known = by_test_set(known_and_open_set(rows)[0])
    figures = write_plots(known, results_dir, swept, classes, scenario.database.fps) if plots else []
    n_runs = rows["run_key"].nunique()
    if is_stream(rows):
        return _stream_report(scenario, results_dir, rows, tables, figures, digest)
    parts = [
        f"# Evaluation: {scenario.name}\n",
        "## Headline\n",
        f"{n_runs} runs ({rows['condition'].nunique()} conditions x {scenario.repeats} repeats x test motions), "
        f"methods: {', '.join(dict.fromkeys(rows['method']))}. Means with 95% bootstrap intervals over runs, three "
        f"significant figures; `correct` is the final recognition accuracy (0-1); `given`: the method is handed "
        f"that quantity; `–`: the method does not produce it. {_test_sets_line(rows)}Scenario hash `{digest}`.\n",
        markdown(tables["headline"]),
        *failed_section(rows),
    ]
    recognises = len(recognising(rows)) > 0    # a scenario of reproduction alone has no recognition sections
    if recognises:
        parts += [
            "## Recognition against time since the start of the motion\n",
            "Fraction of runs whose current most probable class is the true one, at ten evenly spaced instants of "
            "each clip (0 = first frame, 1 = last). An offline method (`full_smoothed`) decides once, at the "
            "end, so its line is flat by construction.\n",
            *_section_plots(figures, ("accuracy_over_time",)),
            "Beside it, the median heading error of the baselink at the same instants (`heading_over_time.csv` "
            "has the 25-75% range), per method that estimates the base pose.\n",
            *_section_plots(figures, ("heading_over_time",)),
            "## Recognition per class\n",
            *_section_plots(figures, ("class_accuracy",)),
            "Right answers out of runs per true class (more columns in `per_class.csv`):\n",
            markdown(tables["class_accuracy"]),
            "The classes answered for motions of other classes (`answers.csv` has every answer): a class a "
            "database answers for whatever it does not know stands at the top.\n",
            markdown(_top_answers(tables["answers"])),
            *_capture_sections(scenario, rows, tables),
        ]
    if len(tables["calibration"]):
        parts += [
            "## Calibration of the final class posterior\n",
            f"Whether a probability means what it says. Confidence: the largest probability of the last frame's "
            f"class posterior (the one that decides the answer). `ece`: expected calibration error over "
            f"{ECE_BINS} equal-mass bins of the runs sorted by confidence (a tie is never split, so `bins` may be "
            f"fewer); `brier`: multi-class Brier score over the whole posterior (0-2); `nll`: mean negative log "
            f"probability of the true class in nats, a probability below {NLL_FLOOR:g} counted as {NLL_FLOOR:g} "
            f"(at most {-math.log(NLL_FLOOR):.1f}); `confident_wrong`: share of the `wrong` answers given with "
            f"confidence above {CONFIDENT:g}. Definitions in `docs/evaluation.md`.\n",
            markdown(tables["calibration"]),
            *_section_plots(figures, ("reliability",)),
            "(bins in `reliability.csv`; all conditions pooled, the number of runs written at each bin)\n",
        ]
    parts += _view_section(figures)
    parts += _pose_sections(tables, figures)
    worst = tables["worst_runs"]
    if len(worst):
        parts += ["## The three worst runs of `full`\n",
                  "Wrong before right, then the lowest log posterior of the true class. Render one (camera image "
                  "with flows, true and estimated body, class posterior over time):\n",
                  markdown(worst), "```bash\n" + "".join(
                      f"python -m harness run-video {results_dir} {k} --out {_video_name(k)}\n"
                      for k in worst["run_key"]) + "```\n"]
    if len(tables["paired_tests"]):
        parts += [
            "## Paired tests (same runs)\n",
            "Exact McNemar test on final recognition and Wilcoxon signed-rank test on camera-frame MPJPE "
            "(protocol 1), `full` against each other method within each condition.\n",
            markdown(tables["paired_tests"]),
        ]
    if recognises:
        parts += [
            "## Confusion matrices (methods that recognise, all conditions)\n",
            *_section_plots(figures, tuple(Path(f).stem for f in figures if Path(f).stem.startswith("confusion_"))),
            "(counts per condition in `confusion.csv`)\n",
        ]
    swept_plots = tuple(Path(f).stem for f in figures if Path(f).stem.startswith("vs_")
                        or Path(f).stem == "accuracy_vs_measured_occlusion")
    if swept_plots:
        parts += ["## Against the swept keys\n", *_section_plots(figures, swept_plots)]
    return _finish(parts, scenario, tables, results_dir)


def _stream_report(scenario: Scenario, results_dir: Path, rows: pd.DataFrame, tables: dict, figures: list[str],
                   digest: str) -> Path:
    """The report of a stream scenario: headline with the segmentation columns, a timeline per run, the worst
    runs, paired tests, plots against the swept keys, the scenario, timing."""
    n_runs = rows["run_key"].nunique()
    parts = [
        f"# Evaluation: {scenario.name}\n",
        "## Headline\n",
        f"{n_runs} stream runs ({rows['condition'].nunique()} conditions x {scenario.repeats} repeats x streams), "
        f"methods: {', '.join(dict.fromkeys(rows['method']))}. Means with 95% bootstrap intervals over runs, three "
        f"significant figures. Recognition is scored per frame on the online labels "
        f"(`docs/streams.md`): `frame_accuracy` leaves transition frames out; `edit_score` and `f1_*` (F1 at "
        f"10/25/50% overlap) compare the recognised segments with the true ones (fractions, 1 = perfect); "
        f"`boundary_delay_s` is the mean delay from a true primitive change to its detection. `given`: the method "
        f"is handed that quantity; `–`: it does not produce it. Scenario hash `{digest}`.\n",
        markdown(tables["headline"]),
        *failed_section(rows),
    ]
    worst = tables["worst_runs"]
    if len(worst):
        parts += ["## The three worst runs of `full`\n", "Lowest frame accuracy first. Render one:\n",
                  markdown(worst), "```bash\n" + "".join(
                      f"python -m harness run-video {results_dir} {k} --out {_video_name(k)}\n"
                      for k in worst["run_key"]) + "```\n"]
    parts += [
        "## Paired tests (same runs)\n",
        "Wilcoxon signed-rank test on camera-frame MPJPE (protocol 1), `full` against each other method.\n",
        markdown(tables["paired_tests"]),
    ]
    swept_plots = tuple(Path(f).stem for f in figures if Path(f).stem.startswith("vs_")
                        or Path(f).stem == "accuracy_vs_measured_occlusion")
    if swept_plots:
        parts += ["## Against the swept keys\n", *_section_plots(figures, swept_plots)]
    parts += _view_section(figures)
    timelines = [f for f in figures if f.startswith("plots/timelines/")]
    if timelines:
        parts += ["## Timelines\n",
                  "Per run: the true labels (top; transitions grey) and the labels each method recognised online, "
                  "with its frame accuracy and F1@25.\n",
                  *[f"![{Path(f).stem}]({f})\n" for f in timelines]]
    return _finish(parts, scenario, tables, results_dir)


MAX_FAILED_LISTED = 50      # failed rows listed in the report (all of them are in runs.csv, column failed)


def failed_rows(rows: pd.DataFrame) -> pd.DataFrame:
    """The rows whose method failed (``failed``: the error's first line; methods from outside the package)."""
    if "failed" not in rows:
        return rows.iloc[:0]
    failed = rows["failed"].fillna("").astype(str)
    return rows[failed != ""]


def failed_section(rows: pd.DataFrame) -> list[str]:
    """The report's list of failed rows, right under the headline (none: no section)."""
    failed = failed_rows(rows)
    if not len(failed):
        return []
    counts = ", ".join(f"`{m}` {n}" for m, n in failed["method"].value_counts(sort=False).items())
    listed = failed[["run_key", "method", "failed"]].head(MAX_FAILED_LISTED)
    listed = listed.assign(failed=listed["failed"].str.replace("|", "\\|"))     # a table cell's bar escaped
    more = (f" The first {MAX_FAILED_LISTED} are listed; all are in `runs.csv` (column `failed`)."
            if len(failed) > MAX_FAILED_LISTED else "")
    return ["## Failed rows\n",
            f"{len(failed)} of {len(rows)} rows failed ({counts}): the method raised, or its estimate broke the "
            f"protocol (`docs/methods.md`). Their metrics are empty and left out of every mean and interval above; "
            f"the other rows are complete.{more}\n",
            markdown(listed.reset_index(drop=True))]


#: Answered-for-others classes the report lists per condition and method (the rest are in ``answers.csv``).
TOP_ANSWERS = 3


def _top_answers(table: pd.DataFrame) -> pd.DataFrame:
    """The ``TOP_ANSWERS`` classes answered most often for other classes' motions, per condition and method."""
    wrong = table[table["for_others"] > 0]
    return wrong.groupby(["condition", "method"], sort=False).head(TOP_ANSWERS).reset_index(drop=True)


def tested_on_captures(scenario: Scenario) -> bool:
    return scenario.test.captures


def _test_sets_line(rows: pd.DataFrame) -> str:
    """The headline's note on its test sets when there are several (each condition is then reported per set),
    and on the open-set rows it leaves out."""
    parts = []
    if "source" in rows and rows["source"].nunique() > 1:
        runs = rows.drop_duplicates("run_key")["source"].value_counts()
        parts.append("Each condition is reported per test set (`condition / set`: " + ", ".join(
            f"{s} {n} runs" for s, n in runs.items()) + ").")
    unknown = known_and_open_set(rows)[1]
    if len(unknown):
        parts.append(f"{unknown['run_key'].nunique()} open-set runs (motions of no class the database has) are left "
                     f"out of every table but their own (\"Open set\").")
    return " ".join(parts) + (" " if parts else "")


HELD_OUT = {"subject": "every row of its subject in its set", "style": "every row of its style in its set",
            "source": "every row of its set", "row": "itself alone",
            "none": "nothing (it is in its own training set: an optimistic bound)"}


def _split_lines(scenario: Scenario) -> list[str]:
    """What each condition's database learns, what a capture test row holds out of it, and which rows were not
    tested and why (``capture_splits.verdicts``)."""
    from collections import Counter

    from harness.evaluation.capture_splits import verdicts
    from harness.evaluation.sweep import conditions

    lines = []
    for cond in conditions(scenario):
        cfg = cond.config
        db, test = cfg.database, cfg.test
        learns = ([f"procedural demonstrations ({db.train_demos} per class)"] if db.learns_procedural else []) + (
            [f"the capture rows of {', '.join(db.capture_sets or ())}"] if db.learns_captures else [])
        line = f"- `{cond.label}`: the database learns {' and '.join(learns)}"
        if db.learns_captures:
            line += f"; a capture test row holds out {HELD_OUT[test.split]}"
        found = verdicts(cfg)
        kinds = Counter(v.kind for v in found)
        line += f". Capture rows tested: {kinds['tested']}, open-set: {kinds['open_set']}"
        skipped = Counter((v.row.set_name, v.why) for v in found if v.kind == "skipped")
        if skipped:
            line += "; not tested: " + "; ".join(f"{n} of {s} ({why})" for (s, why), n in sorted(skipped.items()))
        lines.append(line + ".\n")
    return lines


def _capture_sections(scenario: Scenario, rows: pd.DataFrame, tables: dict) -> list[str]:
    """For scenarios tested on real captures: what each condition's database learned and held out, the classes
    tested, recognition per set and style, the open-set rows, and every confusion matrix as a table."""
    if not tested_on_captures(scenario):
        return []
    classes = list(scenario.classes)
    known = by_test_set(known_and_open_set(rows)[0])
    lines = []
    for cond, grp in known.groupby("condition", sort=False):
        runs = grp.drop_duplicates("run_key")["class_true"].value_counts()
        tested = [c for c in classes if c in runs] + sorted(set(runs.index) - set(classes))
        lines.append(f"- `{cond}`: " + ", ".join(f"{c} ({runs[c]})" for c in tested) + "\n")
    parts = ["### What each split held out\n", "".join(_split_lines(scenario)),
             "### Classes tested\n", "".join(lines)]
    for name, title in (("by_source", "Recognition per capture set"), ("by_style", "Recognition per style"),
                        ("open_set", "Open set: motions of no class the database has")):
        if name in tables and len(tables[name]):
            parts += [f"### {title}\n", markdown(tables[name])]
    for (cond, method), mat in tables["_confusion_matrices"].items():
        table = mat.reset_index().rename(columns={"true": "true \\ answer"})
        parts += [f"### Confusion: `{cond}`, `{method}`\n", markdown(table)]
    return parts


def _view_section(figures: list[str]) -> list[str]:
    """Recognition and heading error against where the camera stood (``plots/by_view.png``), if drawn."""
    if "plots/by_view.png" not in figures:
        return []
    return ["## Against the viewpoint\n",
            "Runs pooled over conditions by the camera's azimuth from the subject's initial heading "
            "(`view_azimuth_deg` in `runs.csv`): front within 45 deg of the face, back within 45 deg of the back, side between. The "
            "heading error up to the twin (dashed, `heading_err_twin_deg`) forgives the depth-reflected mirrored "
            "pose that no flow can tell apart: the gap between the two lines is the information limit, what "
            "remains is the tracker's own error (numbers in `by_view.csv`).\n",
            *_section_plots(figures, ("by_view",))]


# The sections of the tables on the estimated base pose (``tables._estimated_pose_groups``): table, title, text.
POSE_SECTIONS = (
    ("pose_error_split", "What the camera-frame error is made of",
     "`mpjpe_cam_mm` subtracts each skeleton's root, so the baselink's orientation enters it and its position does "
     "not. Per condition and method that estimates the base pose: the correlation over runs of `mpjpe_cam_mm` with "
     "the baselink's rotation error (`corr_rotation`) and with its depth error (`corr_depth`), and the mean "
     "`mpjpe_cam_mm` of the runs whose heading error is within 20 deg (`n_near`, `mpjpe_cam_near`) and beyond 45 "
     "deg (`n_far`, `mpjpe_cam_far`); `mpjpe_pose_mm` is the posture alone."),
    ("heading_spread", "How the heading errors spread",
     "Per condition and method that estimates the base pose, the runs' mean heading errors: their mean and median, "
     "the share within 20 deg (`within_20`), the share settled on the depth-reflected mirrored twin (`on_twin`: "
     "more than 90 deg off, within 45 deg up to the twin), and the mean over the other runs "
     "(`heading_mean_not_twin`). The plot is each share of runs at most so far off (dashed: up to the twin)."),
)


def _pose_sections(tables: dict, figures: list[str]) -> list[str]:
    """``POSE_SECTIONS`` with their tables and the plot of the same name, those whose table has rows (some method
    estimates the base pose)."""
    parts = []
    for name, title, text in POSE_SECTIONS:
        table = tables.get(name)
        if table is not None and len(table):
            parts += [f"## {title}\n", text + "\n", *_section_plots(figures, (name,)), markdown(table)]
    return parts


def _video_name(run_key: str) -> str:
    return "run_" + run_key.replace("/", "_") + ".mp4"


def _finish(parts: list[str], scenario: Scenario, tables: dict, results_dir: Path) -> Path:
    """The report's closing sections (the scenario, timing last) and its atomic write; returns its path."""
    parts = parts + ["## Scenario\n", "```yaml\n" + yaml.safe_dump(scenario.model_dump(mode="json"), sort_keys=False)
                     + "```\n", "## Timing (reported, not part of identity checks)\n", markdown(tables["timing"])]
    path = results_dir / "report.md"
    write_text_atomic(path, "\n".join(parts))
    return path

