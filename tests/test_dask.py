"""The Dask path of the Monte Carlo (``plan --monte-carlo N --scheduler ADDRESS``), on a LocalCluster.

Same seeds, same bits: the runs a Dask worker does must give exactly the rows the local path gives.
Skipped where Dask is not installed (it is in the ``test`` and ``dask`` extras).
"""

from __future__ import annotations

import pandas as pd
import pytest

distributed = pytest.importorskip("dask.distributed")

from gyrorig.montecarlo import fit_monte_carlo  # noqa: E402


def test_dask_local_cluster_gives_the_local_runs():
    kw = dict(scenes=["air-cushion-heavy-top"], seeds=2, duration_s=0.5, terms="data")
    local = fit_monte_carlo(workers=1, **kw)
    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=True, dashboard_address=None) as cl:
        remote = fit_monte_carlo(scheduler=cl.scheduler_address, **kw)
    key = ["scene", "seed", "quantity"]
    cols = [c for c in local.columns if c not in ("wall_s",)]
    a = local.sort_values(key).reset_index(drop=True)[cols]
    b = remote.sort_values(key).reset_index(drop=True)[cols]
    assert len(a) > 0
    pd.testing.assert_frame_equal(a, b)
