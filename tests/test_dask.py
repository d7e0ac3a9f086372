"""``--scheduler ADDRESS``: runs on a Dask cluster give the rows of ``--jobs 1`` (timing aside)."""

import logging

import pandas as pd
import pytest

from harness.evaluation.pipeline import run_one
from harness.evaluation.runner import run_scenario
from harness.evaluation.loading import parse_scenario

distributed = pytest.importorskip("dask.distributed", reason="dask[distributed] is in the test extra")

TINY = {"name": "dask", "seed": 9, "database": {"classes": ["walk", "squat", "kick"], "train_demos": 3, "states": 6},
        "test": {"demos_per_class": 1}, "markers": {"count": 40}, "camera": {"azimuth": "random"},
        "engine": {"tracks": {"particles": 40}, "model": {"points": 40}}}


def test_a_local_cluster_gives_the_rows_of_one_local_job(tmp_path):
    scenario = parse_scenario(TINY)
    cache = tmp_path / "cache"
    serial = run_scenario(scenario, tmp_path / "serial", run_one, jobs=1, cache_dir=cache, progress=False)
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None,
                                  silence_logs=logging.ERROR) as cluster:
        remote = run_scenario(scenario, tmp_path / "dask", run_one, scheduler=cluster.scheduler_address,
                              cache_dir=cache, progress=False)
    assert len(serial) == 3 * len(scenario.methods)             # runs x methods
    pd.testing.assert_frame_equal(serial.drop(columns="ms_per_frame"), remote.drop(columns="ms_per_frame"))
