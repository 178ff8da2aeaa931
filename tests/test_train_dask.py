"""Training on a local ``dask.distributed`` cluster through joblib's dask backend (issue 15).

The README's recipe (``with joblib.parallel_backend("dask"): dop.train(...)``) must give the same
operator as the serial training: the sample solves are independent and their starts do not depend on how
they are split between workers.
"""

from __future__ import annotations

import numpy as np
import pytest

import defop as dop

distributed = pytest.importorskip("distributed")


def test_train_on_a_local_dask_cluster_matches_serial():
    import joblib

    shape = dop.shapes.load("bar")
    m = dop.training.min_samples("tps", shape.n_moving) + 4
    kw = dict(energy="sarap", basis="tps", m=m, seed=3, cache=False, progress=False, rounds=2)
    serial, rec_serial = dop.train(shape, n_jobs=1, **kw)
    with (
        distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cluster,
        distributed.Client(cluster) as client,
    ):
        with distributed.get_task_stream(client) as stream, joblib.parallel_backend("dask"):
            op, rec = dop.train(shape, n_jobs=-1, **kw)
        workers = set(client.scheduler_info()["workers"])
    ran_on = {t["worker"] for t in stream.data}
    assert ran_on and ran_on <= workers  # the sample solves ran in the cluster's worker processes
    assert rec.converged.all() and rec_serial.converged.all()
    scale = np.abs(serial.W).max()
    assert np.abs(op.W - serial.W).max() <= 1e-12 * scale
    np.testing.assert_allclose(rec.X, rec_serial.X, rtol=0, atol=1e-12 * shape.mesh.bbox_diagonal)
