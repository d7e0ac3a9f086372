"""Evaluation: scenarios, the runner, metrics, tables, plots, the report and regression checks.

Submodules are imported where used (``from harness.evaluation.loading import load_scenario``); this package
imports nothing itself, so that importing a metric does not pull in matplotlib or pandas.
"""
