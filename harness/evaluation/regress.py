"""Regression checks: the CI scenario's pooled metrics against a stored baseline, under stated tolerances.

Baseline directory (``results/baseline``):

- ``metrics.json``: ``{"scenario": name, "hash": scenario hash, "metrics": {"<method>/<metric>": value}}``,
  written only by ``harness rebaseline``.
- ``tolerances.yaml``: per metric name (without the method), its kind and tolerance:
  ``higher`` (accuracy-like, 0-1): may drop by at most ``max_drop``;
  ``lower`` (errors): may grow to at most ``stored * (1 + rel) + abs``;
  ``timing``: printed, never gated.

A metric that the baseline has and the current results lack is a regression (a method stopped producing it);
a metric the baseline lacks is printed as ``new`` and not gated.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Literal

import pandas as pd
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from harness import safe_yaml
from harness.errors import HarnessError
from harness.io import read_input_bytes, write_text_atomic

BASELINE_FILE = "metrics.json"
TOLERANCE_FILE = "tolerances.yaml"
MAX_FILE_BYTES = 16 * 2**20      # a baseline, tolerance or metrics file


class RegressError(HarnessError):
    """A missing or malformed baseline or tolerance file."""


class Tolerance(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)

    kind: Literal["higher", "lower", "timing"]
    max_drop: float = Field(0.05, ge=0)   # higher: absolute drop allowed (0.05 = 5 points of accuracy)
    rel: float = Field(0.15, ge=0)        # lower: relative growth allowed
    abs: float = Field(0.0, ge=0)         # lower: absolute slack on top, in the metric's unit


class Tolerances(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)

    metrics: dict[str, Tolerance]


def load_tolerances(path: str | Path) -> dict[str, Tolerance]:
    """The tolerance file, read like a scenario (``harness.safe_yaml``: bounded, duplicate keys refused); every
    error is one line naming the file and, for YAML errors, the line."""
    path = Path(path)
    if not path.is_file():
        raise RegressError(f"{path}: no tolerance file")
    raw = safe_yaml.load(path, RegressError, "tolerance", MAX_FILE_BYTES)
    try:
        return Tolerances.model_validate(raw).metrics
    except ValidationError as exc:
        err = exc.errors()[0]
        loc = ".".join(str(p) for p in err["loc"])
        msg = "unknown key" if err["type"] == "extra_forbidden" else err["msg"]
        raise RegressError(f"{path}: {loc}: {msg}") from None


def load_baseline(path: str | Path) -> dict:
    path = Path(path)
    if not path.is_file():
        raise RegressError(f"{path}: no stored baseline (create it with `harness rebaseline`)")
    data = _json(path, "baseline")
    if not isinstance(data, dict) or not isinstance(data.get("metrics"), dict):
        raise RegressError(f"{path}: expected an object with a 'metrics' mapping")
    _numbers(data["metrics"], path)
    return data


def _numbers(metrics: dict, path: Path) -> None:
    for key, value in metrics.items():
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise RegressError(f"{path}: metric {str(key)[:60]!r} must be a number")


def _json(path: Path, kind: str):
    """A JSON file's value; one-line ``RegressError`` for a file too large, not JSON, or nested too deeply."""
    data = read_input_bytes(path, RegressError, kind, MAX_FILE_BYTES)
    try:
        return json.loads(data)
    except json.JSONDecodeError as exc:
        raise RegressError(f"{path}: line {exc.lineno}: not valid JSON ({exc.msg})") from None
    except (ValueError, RecursionError):
        raise RegressError(f"{path}: not valid JSON (not UTF-8, a malformed number or nested too deeply)") from None


def _limit(tol: Tolerance, stored: float) -> tuple[float, str]:
    if tol.kind == "higher":
        return stored - tol.max_drop, f">= stored - {tol.max_drop:g}"
    if tol.kind == "lower":
        return stored * (1 + tol.rel) + tol.abs, f"<= stored x {1 + tol.rel:g} + {tol.abs:g}"
    return math.nan, "not gated"


def compare(stored: dict[str, float], now: dict[str, float], tolerances: dict[str, Tolerance]) -> pd.DataFrame:
    """One row per metric: metric, stored, now, tolerance, verdict (``ok``, ``REGRESSED``, ``MISSING``,
    ``timing``, ``new``, ``no tolerance``). Only ``REGRESSED`` and ``MISSING`` fail."""
    rows = []
    for key in sorted(set(stored) | set(now)):
        name = key.split("/", 1)[-1]
        tol = tolerances.get(name)
        s, n = stored.get(key, math.nan), now.get(key, math.nan)
        if key not in stored:
            rows.append((key, s, n, "", "new"))
            continue
        if tol is None:
            rows.append((key, s, n, "", "no tolerance"))
            continue
        bound, text = _limit(tol, s)
        if tol.kind == "timing":
            verdict = "timing"
        elif key not in now or not math.isfinite(n):
            verdict = "MISSING"
        elif (tol.kind == "higher" and n < bound) or (tol.kind == "lower" and n > bound):
            verdict = "REGRESSED"
        else:
            verdict = "ok"
        rows.append((key, s, n, text, verdict))
    return pd.DataFrame(rows, columns=["metric", "stored", "now", "tolerance", "verdict"])


def failed(table: pd.DataFrame) -> bool:
    return bool(table["verdict"].isin(["REGRESSED", "MISSING"]).any())


def format_table(table: pd.DataFrame) -> str:
    """Fixed-width text for the terminal."""
    def num(x):
        return "-" if not math.isfinite(x) else f"{x:.4g}"
    w = max([len("metric")] + [len(m) for m in table["metric"]])
    lines = [f"{'metric':{w}s}  {'stored':>10s}  {'now':>10s}  {'tolerance':24s}  verdict"]
    for r in table.itertuples(index=False):
        lines.append(f"{r.metric:{w}s}  {num(r.stored):>10s}  {num(r.now):>10s}  {r.tolerance:24s}  {r.verdict}")
    return "\n".join(lines)


def check(results_dir: str | Path, baseline_dir: str | Path) -> tuple[pd.DataFrame, dict]:
    """Compare ``results_dir/metrics.json`` (written by the tables) with the baseline; returns the table and
    the stored baseline record."""
    now_path = Path(results_dir) / "metrics.json"
    if not now_path.is_file():
        raise RegressError(f"{now_path}: no current metrics (run the CI scenario first)")
    baseline = load_baseline(Path(baseline_dir) / BASELINE_FILE)
    tolerances = load_tolerances(Path(baseline_dir) / TOLERANCE_FILE)
    now = _json(now_path, "metrics")
    if not isinstance(now, dict):
        raise RegressError(f"{now_path}: expected a mapping of metric names to numbers")
    _numbers(now, now_path)
    return compare(baseline["metrics"], now, tolerances), baseline


def rebaseline(results_dir: str | Path, baseline_dir: str | Path, scenario_name: str, digest: str) -> Path:
    """Store the current pooled metrics as the new baseline (tolerances are left as they are)."""
    now_path = Path(results_dir) / "metrics.json"
    if not now_path.is_file():
        raise RegressError(f"{now_path}: no current metrics to store (run the CI scenario first)")
    record = {"scenario": scenario_name, "hash": digest, "metrics": json.loads(now_path.read_text())}
    path = Path(baseline_dir) / BASELINE_FILE
    write_text_atomic(path, json.dumps(record, indent=2, sort_keys=True) + "\n")
    return path
