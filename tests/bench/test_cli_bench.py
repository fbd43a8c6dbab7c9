"""`gfjax bench`: end to end on a small labelled LAZ, the JSON schema, skipped peers, bad input."""
from __future__ import annotations

import json
import math
import sys

import pytest
from bench_helpers import write_scene_laz

from gfjax.bench import peers
from gfjax.bench import run as bench
from gfjax.cli.main import main
from gfjax.metrics import DTM_KEYS, POINT_KEYS

pytestmark = pytest.mark.slow          # tens of seconds per test: run first (conftest)

TOP_KEYS = {"schema", "gfjax_version", "command", "created_utc", "machine", "repeat", "threads", "compile_cache",
            "dtm_cell_m", "notes", "runs", "summary"}


@pytest.fixture(scope="module")
def scene(tmp_path_factory):
    folder = tmp_path_factory.mktemp("bench")
    return write_scene_laz(folder / "scene.laz"), write_scene_laz(folder / "unlabelled.laz", labelled=False)


def test_bench_smrf_end_to_end_with_a_missing_peer(scene, tmp_path, capsys, monkeypatch):
    labelled = scene[0]
    monkeypatch.setitem(sys.modules, "pysmrf", None)          # as if the [bench] extra were absent
    out_json, out_png = tmp_path / "bench.json", tmp_path / "bench.png"
    code = main(["bench", str(labelled), "--methods", "smrf", "--peers", "pysmrf",
                 "--repeat", "2", "--threads", "1", "--json", str(out_json), "--plot", str(out_png)])
    captured = capsys.readouterr()
    assert code == 0, captured.err
    assert "peer pysmrf skipped: not installed" in captured.err
    assert "scene.laz" in captured.out and "gfjax smrf" in captured.out
    assert out_png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"

    doc = json.loads(out_json.read_text())
    assert set(doc) == TOP_KEYS and doc["schema"] == bench.SCHEMA and doc["repeat"] == 2 and doc["threads"] == 1
    assert doc["compile_cache"] is False
    assert doc["notes"] == [peers.skip_note("pysmrf")]
    assert doc["machine"]["nproc"] >= 1
    (run,) = doc["runs"]
    assert set(run) == set(bench.RECORD_KEYS)
    assert run["file"] == str(labelled) and run["filter"] == "gfjax smrf"
    assert run["status"] == "ok" and run["error"] is None and run["kind"] == "method"
    assert run["n_points"] == run["n_used"] == 3000 and run["n_cpus"] == 1
    assert len(run["filter_times_s"]) == len(run["job_times_s"]) == 2
    assert 0 < run["filter_s"] <= run["job_s"]
    assert run["compile_s"] > 0 and run["first_call_s"] > run["compile_s"]
    assert run["peak_rss_mib"] > run["baseline_rss_mib"] > 0
    assert math.isclose(run["points_per_s"], run["n_points"] / run["job_s"])
    assert set(run["point_metrics"]) == set(POINT_KEYS) and set(run["dtm_metrics"]) == set(DTM_KEYS)
    assert run["point_metrics"]["total_error"] < 0.05 and run["point_metrics"]["kappa"] > 0.9
    assert run["dtm_metrics"]["rmse_m"] < 0.2
    (summary,) = doc["summary"]
    assert summary["filter"] == "gfjax smrf" and summary["n_files"] == summary["n_labelled"] == 1
    assert summary["mean_total_error"] == run["point_metrics"]["total_error"]


def test_bench_peer_only_labelled_and_unlabelled(scene, tmp_path, capsys):
    if not peers.installed("cloth-simulation-filter"):
        pytest.skip("cloth-simulation-filter not installed (pip install -e '.[bench]')")
    out_json, out_png = tmp_path / "peer.json", tmp_path / "peer.png"
    code = main(["bench", *map(str, scene), "--methods", "none", "--peers", "cloth-simulation-filter",
                 "--json", str(out_json), "--plot", str(out_png)])
    assert code == 0, capsys.readouterr().err
    doc = json.loads(out_json.read_text())
    scored, unscored = doc["runs"]
    assert [r["file"] for r in doc["runs"]] == list(map(str, scene))
    assert scored["kind"] == unscored["kind"] == "peer" and scored["compile_s"] is None
    assert scored["point_metrics"]["total_error"] < 0.1
    assert unscored["point_metrics"] is None and unscored["dtm_metrics"] is None
    (summary,) = doc["summary"]
    assert summary["n_files"] == 2 and summary["n_labelled"] == 1
    assert out_png.exists()


@pytest.mark.parametrize("options, message", [
    (["--methods", "smrf,nosuch"], "--methods: unknown method 'nosuch'"),
    (["--peers", "nosuch"], "--peers: unknown peer 'nosuch'"),
    (["--methods", "none", "--peers", "none"], "nothing to run"),
    (["--repeat", "0"], "--repeat: must be an integer >= 1 and <= 10000, got 0"),
    (["--threads", "100000"], "--threads: threads must be between 1 and"),
    (["--json", "out.txt"], "--json out.txt: output must end in .json"),
    (["--plot", "out.jpg"], "--plot out.jpg: output must end in .png"),
    (["--methods", "smrf", "--model", "m.eqx"], "--model m.eqx: only the sparsegf method takes a model"),
    (["--methods", "sparsegf", "--model", "m.eqx"], "m.eqx: model file not found"),
])
def test_bad_options_exit_2(scene, options, message, capsys, monkeypatch, tmp_path):
    monkeypatch.chdir(tmp_path)
    assert main(["bench", str(scene[0]), *options]) == 2
    err = capsys.readouterr().err
    assert message in err and err.count("\n") == 1
    assert list(tmp_path.iterdir()) == []


def test_missing_input_exits_2(tmp_path, capsys):
    assert main(["bench", str(tmp_path / "absent.laz"), "--methods", "smrf"]) == 2
    assert "absent.laz: no such file" in capsys.readouterr().err


def test_a_failing_run_is_a_row_not_a_crash(scene):
    record = bench.run_one(scene[0], bench.Runner("peer", "not-a-peer"))
    assert record["status"] == "failed" and "not-a-peer" in record["error"]
    assert set(record) == set(bench.RECORD_KEYS) and record["job_s"] is None
    table = bench.format_table([record])
    assert "failed" in table and "not-a-peer" in table
    assert bench.summarize([record])[0]["n_failed"] == 1
    assert not bench.has_accuracy([record])


def test_json_safe_turns_nan_into_null():
    assert bench.json_safe({"a": [1.0, float("nan")], "b": (float("inf"), "x")}) == {"a": [1.0, None], "b": [None, "x"]}


def test_run_one_passes_threads_and_compile_cache_and_derives_rates(monkeypatch, tmp_path):
    seen = {}

    def fake_run_isolated(target, kwargs, **options):
        seen.update(target=target, kwargs=kwargs, **options)
        return {"n_points": 2_000_000, "n_used": 2_000_000, "n_ground": 10, "n_cpus": 1, "job_s": 4.0,
                "filter_s": 2.0, "compile_s": 1.5, "peak_rss_bytes": 300 << 20, "baseline_rss_bytes": 100 << 20,
                "point_metrics": None, "dtm_metrics": None, "not_a_record_key": 1}

    monkeypatch.setattr(bench.harness, "run_isolated", fake_run_isolated)
    record = bench.run_one(tmp_path / "x.laz", bench.Runner("method", "smrf"), repeat=3, threads=1,
                           compile_cache=tmp_path / "cache")
    assert seen["target"] == "gfjax.bench.job:bench_one"
    assert seen["kwargs"] == {"path": str(tmp_path / "x.laz"), "kind": "method", "name": "smrf",
                              "repeat": 3, "units": None, "model": None}
    assert seen["cpus"] == bench.harness.choose_cpus(1) and seen["keep_compile_cache"] is True
    assert seen["env"]["JAX_COMPILATION_CACHE_DIR"] == str(tmp_path / "cache")
    assert set(record) == set(bench.RECORD_KEYS) and record["status"] == "ok"
    assert record["points_per_s"] == 500_000 and record["filter_points_per_s"] == 1_000_000
    assert record["peak_rss_mib"] == 300 and record["rss_per_million_points_mib"] == 100


def test_bench_runs_sparsegf_with_the_model_it_is_given(scene, tmp_path):
    import jax
    import numpy as np

    from gfjax import sparsegf
    from gfjax.bench import job
    from gfjax.io import las as las_io
    from gfjax.sparsegf import checkpoint
    from gfjax.sparsegf.features import n_features
    from gfjax.sparsegf.model import NetConfig

    net = sparsegf.init(NetConfig(stem=4, planes=(4,) * 8, layers=(1,) * 8, refine=4, in_features=n_features("xyz+tophat")),
                        key=jax.random.key(5))
    model = tmp_path / "micro.eqx"
    checkpoint.save(model, net, {"config": {"features": "xyz+tophat"}})
    runners, _ = bench.plan("sparsegf", "none", model=str(model))
    assert [r.label for r in runners] == ["gfjax sparsegf (micro.eqx)"]
    record = job.bench_one(path=str(scene[0]), kind="method", name="sparsegf", model=str(model))
    want = sparsegf.filter(las_io.read(scene[0]), model=str(model)).ground
    assert 0 < record["n_ground"] == int(np.sum(want)) < len(want)
