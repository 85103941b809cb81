"""Fleets: `bench` on a Dask LocalCluster gives the same figures as on the local process pool."""
from __future__ import annotations

import json

import pytest

import distributed      # in the dev extras: a missing install fails here, in CI too

from ahrsgen import bench
from ahrsgen.sim.fleet import Fleet
from ahrsgen.sim.readers import EXCERPTS

pytestmark = pytest.mark.slow       # tests/README.md: left out of the quick run


def _figures(rep):
    return {k: rep[k] for k in ("scenarios", "broad", "px4", "run_errors", "build_errors", "site_sets")}


def test_bench_on_local_cluster_equals_local_pool(tmp_path):
    kw = dict(quick=True, filters=["qcf"], peer_names=("madgwick",), scenario_labels=["turntable"])
    local = bench.bench(out_dir=tmp_path / "local", jobs=2, **kw)
    with distributed.LocalCluster(n_workers=1, threads_per_worker=2, processes=False,
                                  dashboard_address=None) as cluster:
        dask = bench.bench(out_dir=tmp_path / "dask", scheduler=cluster.scheduler_address, **kw)
    a, b = _figures(local), _figures(dask)
    assert a["scenarios"] and a["broad"]["trials"]
    assert json.dumps(a, sort_keys=True) == json.dumps(b, sort_keys=True)


def test_fleet_map_keeps_order_and_reports_where():
    with Fleet(workers=2) as f:
        assert f.map(abs, [-3, 1, -2]) == [3, 1, 2]
        assert "2 local" in f.where
    with distributed.LocalCluster(n_workers=1, processes=False, dashboard_address=None) as cluster:
        with Fleet(scheduler=cluster.scheduler_address) as f:
            assert f.map(abs, [-3, 1, -2]) == [3, 1, 2]
            assert "Dask" in f.where


def test_unreachable_scheduler_is_a_config_error():
    import pytest
    from ahrsgen.codegen.model import ConfigError
    with pytest.raises(ConfigError, match="cannot reach the Dask scheduler at tcp://127.0.0.1:9"):
        Fleet(scheduler="tcp://127.0.0.1:9", timeout="2s")


def test_tune_on_local_cluster_equals_local(tmp_path):
    from ahrsgen import tune
    data = EXCERPTS
    cases = tune.collect_cases([data / "broad_01_excerpt.csv.gz", data / "px4_handheld_excerpt.ulg"])
    kw = dict(budget=3, folds=0, progress=False, out=open("/dev/null", "w"))

    def outcome(**where):
        """What a user gets: the tuned values and scores, or the one-line refusal of a tune
        that does not beat its starting values (a 3-trial budget often does not)."""
        try:
            r = tune.tune("qcf", ["kp", "ki"], cases, **where, **kw)
            return r["tuned"], r["train"]
        except tune.TuneFailed as e:
            return str(e)
    local = outcome(workers=2)
    with distributed.LocalCluster(n_workers=1, threads_per_worker=2, processes=False,
                                  dashboard_address=None) as cluster:
        dask = outcome(scheduler=cluster.scheduler_address)
    assert local == dask
