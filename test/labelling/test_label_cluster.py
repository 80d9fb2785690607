"""grasp-fc-label on real Dask clusters: a LocalCluster of 2 worker processes, and a
scheduler with workers started as separate processes on 127.0.0.1, one of them killed."""

import contextlib
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from grasp_fc_ros.core import check_force_closure
from grasp_fc_ros.core.model.grasp_input import show_value
from grasp_fc_ros.labelling import InputError, Plan, cli, dask_client, object_sources, run, runner
from grasp_fc_ros.labelling.output import Output
from grasp_fc_ros.objects import make_object, sample_grasps
from waiting import wait_for

DASK = Path(sys.executable).with_name("dask")
CHUNK = 700


def _box_grasps(n_grasps, n_fingers, seed):
    return sample_grasps(make_object("box", n_points=2000), n_grasps, n_fingers,
                         np.random.default_rng(seed))


@pytest.fixture(scope="module")
def client():
    with dask_client(workers=2) as dask:
        assert len(dask.scheduler_info()["workers"]) == 2
        yield dask


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    """Three inputs (stored .npz, compressed .npz with ids, nested Parquet) and the labels
    the core gives in-process, chunk by chunk."""
    folder = tmp_path_factory.mktemp("inputs")
    rng = np.random.default_rng(7)
    p, n = _box_grasps(3000, 6, 1)
    mu_a = rng.uniform(0.2, 0.8, 3000)
    np.savez(folder / "a.npz", positions=p, normals=n, mu=mu_a)
    q, m = _box_grasps(1000, 6, 2)
    ids_b = 10**12 + 7919 * np.arange(1000, dtype=np.uint64)[::-1]  # distinct, unordered
    np.savez_compressed(folder / "b.npz", positions=q, normals=m, mu=0.5, ids=ids_b)
    r, k = _box_grasps(1100, 5, 3)
    mu_c = rng.uniform(0.2, 0.8, (1100, 5))
    pq.write_table(pa.table({
        "positions": pa.array(r.tolist(), pa.list_(pa.list_(pa.float64(), 3))),
        "normals": pa.array(k.tolist(), pa.list_(pa.list_(pa.float64(), 3))),
        "mu": pa.array(mu_c.tolist(), pa.list_(pa.float64()))}), folder / "c.parquet",
        row_group_size=300)

    expected = {"id": [], "force_closure": [], "status": [], "margin": []}
    inputs = [(p, n, mu_a[:, None], np.arange(3000)), (q, m, np.full((1000, 1), 0.5), ids_b),
              (r, k, mu_c, 4000 + np.arange(1100))]
    for positions, normals, mu, ids in inputs:
        for start in range(0, len(positions), CHUNK):
            part = slice(start, start + CHUNK)
            result = check_force_closure(positions[part], normals[part], mu[part])
            expected["id"].append(ids[part])
            for key in ("force_closure", "status", "margin"):
                expected[key].append(getattr(result, key))
    expected = {key: np.concatenate(values) for key, values in expected.items()}
    paths = [str(folder / name) for name in ("a.npz", "b.npz", "c.parquet")]
    return paths, expected


def _plan(paths, chunk=CHUNK):
    return Plan.from_files(paths, chunk_size=chunk)


def _assert_equals_expected(table, expected):
    assert table.num_rows == len(expected["id"])
    assert np.array_equal(table["id"].to_numpy(), expected["id"])
    assert len(np.unique(table["id"].to_numpy())) == table.num_rows
    for key in ("force_closure", "status"):
        assert np.array_equal(table[key].to_numpy(), expected[key]), key
    assert np.array_equal(table["margin"].to_numpy(), expected["margin"], equal_nan=True)


def test_local_cluster_equals_core_in_process(client, dataset, tmp_path):
    paths, expected = dataset
    summary = run(_plan(paths), tmp_path / "out", client, progress=False)
    assert summary.chunks_written == len(_plan(paths).chunks) == 5 + 2 + 2
    assert summary.grasps_written == 5100
    table = pq.read_table(tmp_path / "out")
    _assert_equals_expected(table, expected)
    assert sum(summary.status_counts.values()) == 5100
    assert summary.status_counts["FORCE_CLOSURE"] == int(expected["force_closure"].sum())
    # The verdicts are those of one big in-process batch too.
    a = np.load(paths[0])
    whole = check_force_closure(a["positions"], a["normals"], a["mu"][:, None])
    assert np.array_equal(table["force_closure"].to_numpy()[:3000], whole.force_closure)


def test_single_file_output_and_rerun(client, dataset, tmp_path):
    paths, expected = dataset
    out = tmp_path / "labels.parquet"
    run(_plan(paths), out, client, progress=False)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["labels.parquet"]
    assert pq.ParquetFile(out).metadata.num_row_groups == 9
    _assert_equals_expected(pq.read_table(out), expected)
    again = run(_plan(paths), out, client, progress=False)
    assert (again.chunks_written, again.chunks_skipped) == (0, 9)
    with pytest.raises(Exception, match="another run"):
        run(_plan(paths, chunk=500), out, client, progress=False)


def test_resumes_after_interrupted_run(client, dataset, tmp_path, monkeypatch):
    paths, expected = dataset
    out = tmp_path / "out"
    real_write = Output.write_part
    written = []

    def write_two_then_die(self, name, table):
        if len(written) == 2:
            raise KeyboardInterrupt
        real_write(self, name, table)
        written.append(name)

    monkeypatch.setattr(Output, "write_part", write_two_then_die)
    with pytest.raises(KeyboardInterrupt):
        run(_plan(paths), out, client, progress=False)
    monkeypatch.undo()
    assert sorted(p.name for p in out.glob("part-*")) == sorted(written)
    (out / ".part-00000-000000.parquet.deadbeef.tmp").write_bytes(b"half")  # a killed write
    summary = run(_plan(paths), out, client, progress=False)
    assert (summary.chunks_written, summary.chunks_skipped) == (7, 2)
    assert not list(out.glob(".*"))
    _assert_equals_expected(pq.read_table(out), expected)


def test_bad_value_found_on_a_worker_writes_nothing(client, dataset, tmp_path):
    paths, _ = dataset
    a = dict(np.load(paths[0]))
    a["normals"][2345, 4] = np.nan
    np.savez(tmp_path / "bad.npz", **a)
    with pytest.raises(InputError) as error:
        run(_plan([paths[1], str(tmp_path / "bad.npz")]), tmp_path / "out", client,
            progress=False)
    assert str(error.value) == (f"{tmp_path / 'bad.npz'}: grasp 2345 (id 3345), contact 4: "
                                "normal is not finite, got (nan, nan, nan)")
    assert not (tmp_path / "out").exists()


def test_grasps_drawn_on_objects_and_relabelled(client, tmp_path):
    trimesh = pytest.importorskip("trimesh")
    trimesh.creation.box(extents=(0.08, 0.05, 0.03)).export(tmp_path / "brick.obj")
    sources = object_sources(["torus"], [tmp_path / "brick.obj"], grasps_per_object=900,
                             fingers=4, mu=0.4, seed=3, points=800, draw_block=400)
    summary = run(Plan(sources, chunk_size=400), tmp_path / "ds", client, progress=False)
    assert summary.chunks_written == 6
    table = pq.read_table(tmp_path / "ds")
    assert table["object"].to_pylist() == ["torus"] * 900 + ["brick"] * 900
    assert np.array_equal(table["id"].to_numpy(), np.arange(1800))
    # The grasps are the chunk's own random stream's, labelled by the core.
    surface = sources[1].surface
    p, n = sample_grasps(surface, 400, 4, np.random.default_rng([3, 1, 1]))
    rows = table.slice(900 + 400, 400)
    assert np.array_equal(np.stack(rows["positions"].to_numpy(zero_copy_only=False))
                          .reshape(400, 4, 3), p)
    assert np.array_equal(rows["status"].to_numpy(), check_force_closure(p, n, 0.4).status)
    # The output is a valid Parquet input: labelling it again gives the same labels.
    pq.write_table(table, tmp_path / "ds.parquet")
    again = run(_plan([str(tmp_path / "ds.parquet")], chunk=400), tmp_path / "again",
                client, progress=False)
    assert again.grasps_written == 1800
    relabelled = pq.read_table(tmp_path / "again")
    for key in ("id", "status"):
        assert relabelled[key].equals(table[key]), key
    # Other chunk boundaries: the core's batched solves may move margins by rounding.
    np.testing.assert_allclose(relabelled["margin"].to_numpy(), table["margin"].to_numpy(),
                               rtol=0, atol=1e-7)


def test_quality_columns_on_the_cluster_equal_the_core(client, tmp_path):
    from grasp_fc_ros.core import epsilon_quality

    p, n = _box_grasps(600, 4, 21)
    np.savez(tmp_path / "q.npz", positions=p, normals=n, mu=0.5)
    plan = Plan.from_files([str(tmp_path / "q.npz")], chunk_size=250, quality_rtol=1e-3)
    run(plan, tmp_path / "labels.parquet", client, progress=False)
    table = pq.read_table(tmp_path / "labels.parquet")
    assert table.schema.equals(plan.schema)
    fc = table["force_closure"].to_numpy()
    lower, upper = table["epsilon_lower"].to_numpy(), table["epsilon_upper"].to_numpy()
    for start in range(0, 600, 250):
        part = slice(start, start + 250)
        expected = epsilon_quality(p[part], n[part], 0.5)
        assert np.array_equal(lower[part], expected.lower)
        assert np.array_equal(upper[part], expected.upper)
    assert fc.any() and np.all((lower > 0) == fc)


def test_cli_robustness_on_drawn_grasps_keeps_the_grasps_and_resumes(client, tmp_path,
                                                                     capsys, monkeypatch):
    from grasp_fc_ros.labelling.robustness import Robustness
    from grasp_fc_ros.labelling.runner import default_chunk_size
    from grasp_fc_ros.labelling.tasks import label_chunk

    monkeypatch.setattr(runner, "dask_client", lambda *args: contextlib.nullcontext(client))
    drawn = ["--objects", "box", "--grasps-per-object", "2000", "--fingers", "4", "--mu",
             "0.6", "--seed", "5", "--no-progress"]
    robust = ["--robustness", "--normal-error", "0.02", "--normal-sigma", "0.03",
              "--samples", "20"]
    assert cli.main([*drawn, "--out", str(tmp_path / "plain")]) == 0
    assert cli.main([*drawn, *robust, "--out", str(tmp_path / "robust")]) == 0
    capsys.readouterr()
    settings = Robustness(normal_error=0.02, normal_sigma=0.03, samples=20, seed=5)
    size = default_chunk_size(None, settings)
    assert size < 2000  # chunks by cost, smaller than the blocks the grasps are drawn in
    assert len(list((tmp_path / "robust").glob("part-*"))) == -(-2000 // size)
    plain, robust_table = pq.read_table(tmp_path / "plain"), pq.read_table(tmp_path / "robust")
    for key in ("id", "positions", "normals", "status"):
        assert robust_table[key].equals(plain[key]), key  # the same grasps, the same labels
    # The robustness columns are those of one chunk of all 2,000 grasps in one process.
    source = object_sources(["box"], [], 2000, 4, 0.6, 5, 5000, draw_block=50_000)[0]
    expected = label_chunk(source, 0, 2000, "auto", "seed", robustness=settings)
    for key in ("holds", "holds_name", "holds_bound", "probability_successes"):
        assert robust_table[key].equals(expected[key]), key
    for key in ("normal_angle", "position_radius", "friction_drop", "probability_estimate",
                "probability_lower", "probability_upper", "probability_normal_lower_bound"):
        assert np.array_equal(robust_table[key].to_numpy(), expected[key].to_numpy(),
                              equal_nan=True), key
    # The same command resumes (nothing to do); other samples are refused, naming them.
    assert cli.main([*drawn, *robust, "--out", str(tmp_path / "robust")]) == 0
    assert f"({-(-2000 // size)} already written)" in capsys.readouterr().err
    robust[-1] = "25"
    assert cli.main([*drawn, *robust, "--out", str(tmp_path / "robust")]) == 2
    assert "other options (--samples); remove it" in capsys.readouterr().err


# --- a scheduler and workers as separate processes -------------------------------------


@pytest.fixture
def processes(tmp_path):
    """A `dask scheduler` and a way to start `dask worker` processes, all on 127.0.0.1."""
    scheduler_file = tmp_path / "scheduler.json"
    started = []

    def start(*args):
        proc = subprocess.Popen([str(DASK), *args], stdout=subprocess.DEVNULL,
                                stderr=subprocess.DEVNULL)
        started.append(proc)
        return proc

    # Killed whatever happens, also when the scheduler never comes up: a leaked
    # scheduler outlives the test run.
    try:
        start("scheduler", "--host", "127.0.0.1", "--port", "0", "--no-dashboard",
              "--scheduler-file", str(scheduler_file))
        wait_for(scheduler_file.exists, 60, "the scheduler")
        address = json.loads(scheduler_file.read_text())["address"]

        def worker():
            return start("worker", address, "--nthreads", "1", "--no-nanny", "--host",
                         "127.0.0.1", "--no-dashboard")

        yield address, worker, scheduler_file
    finally:
        for proc in reversed(started):
            proc.kill()
            proc.wait()


def _big_input(tmp_path, n_grasps):
    p, n = _box_grasps(n_grasps, 6, 11)
    np.savez(tmp_path / "big.npz", positions=p, normals=n, mu=0.5)
    return str(tmp_path / "big.npz")


# Grasps of the worker-kill run, in chunks of 300. With 9,000 (~1 s of run here) the test
# timed out twice in full runs waiting to see both workers busy, which the end of the run
# would explain; 60,000 last several seconds. The wait now also ends with the run, and
# the test then fails on parts_at_kill: the kill must come mid-run.
N_KILL_GRASPS = 60_000


def test_worker_killed_mid_run_loses_nothing(processes, tmp_path):
    address, start_worker, _ = processes
    workers = [start_worker(), start_worker()]
    path = _big_input(tmp_path, N_KILL_GRASPS)
    out = tmp_path / "out"
    with dask_client(address) as dask:
        dask.wait_for_workers(2, timeout=60)
        plan = _plan([path], chunk=300)
        n_chunks = N_KILL_GRASPS // 300
        runner = subprocess.Popen([sys.executable, "-m", "grasp_fc_ros.labelling.cli", path,
                                   "--out", str(out), "--chunk-size", "300", "--scheduler",
                                   address, "--no-progress"], stderr=subprocess.PIPE,
                                  text=True)
        wait_for(lambda: len(list(out.glob("part-*"))) >= 3, 120, "the first parts")
        # Kill a worker while both run chunks (between two chunks one may be idle for a
        # moment, more so on a loaded machine).
        def both_busy_or_run_over():
            busy = dask.processing()
            return (len(busy) == 2 and all(busy.values())) or runner.poll() is not None

        wait_for(both_busy_or_run_over, 60, "both workers running chunks")
        workers[0].kill()
        workers[0].wait()
        parts_at_kill = len(list(out.glob("part-*")))
        stderr = runner.communicate(timeout=240)[1]
    assert runner.returncode == 0, stderr
    assert parts_at_kill < n_chunks  # the kill came mid-run
    assert f"{N_KILL_GRASPS:,} grasps labelled in {n_chunks} chunk(s)" in stderr
    table = pq.read_table(out)
    ids = table["id"].to_numpy()
    assert np.array_equal(ids, np.arange(N_KILL_GRASPS))  # none lost or twice, in order
    d = np.load(path)
    expected = np.concatenate([check_force_closure(d["positions"][s:s + 300],
                                                   d["normals"][s:s + 300], 0.5).status
                               for s in range(0, N_KILL_GRASPS, 300)])
    assert np.array_equal(table["status"].to_numpy(), expected)
    assert len(plan.chunks) == len(list(out.glob("part-*"))) == n_chunks


# Grasps of the resumed run, in chunks of 300: with 6,000 (20 chunks, a fraction of a
# second once the first parts are out) the run could end between the test seeing four
# parts and its kill, on a loaded machine; 200 chunks take seconds.
N_RESUME_GRASPS = 60_000


def test_killed_client_resumes_on_the_same_cluster(processes, tmp_path, capsys):
    address, start_worker, _ = processes
    start_worker(), start_worker()
    path = _big_input(tmp_path, N_RESUME_GRASPS)
    out = tmp_path / "labels.parquet"
    command = [path, "--out", str(out), "--chunk-size", "300", "--scheduler", address,
               "--no-progress"]
    runner = subprocess.Popen([sys.executable, "-m", "grasp_fc_ros.labelling.cli", *command],
                              stderr=subprocess.DEVNULL)
    parts = Path(str(out) + ".parts")
    wait_for(lambda: len(list(parts.glob("part-*"))) >= 4, 120, "the first parts")
    runner.kill()
    runner.wait()
    done = len(list(parts.glob("part-*")))
    assert 4 <= done < N_RESUME_GRASPS // 300
    assert cli.main(command) == 0
    assert f"({done} already written)" in capsys.readouterr().err
    assert not parts.exists()
    table = pq.read_table(out)
    assert np.array_equal(table["id"].to_numpy(), np.arange(N_RESUME_GRASPS))
    d = np.load(path)
    fresh = check_force_closure(d["positions"][:300], d["normals"][:300], 0.5)
    assert np.array_equal(table["status"].to_numpy()[:300], fresh.status)


def test_cli_nan_on_a_cluster_exits_2_naming_file_and_grasp(processes, tmp_path, capsys):
    _, start_worker, scheduler_file = processes
    start_worker()
    p, n = _box_grasps(900, 4, 5)
    p[801, 1, 0] = np.inf
    np.savez(tmp_path / "g.npz", positions=p, normals=n, mu=0.5)
    code = cli.main([str(tmp_path / "g.npz"), "--out", str(tmp_path / "o"),
                     "--chunk-size", "200", "--scheduler-file", str(scheduler_file)])
    assert code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"grasp-fc-label: error: {tmp_path / 'g.npz'}: grasp 801 (id 801), "
                   f"contact 1: position is not finite, got {show_value(p[801, 1])}"]
    assert not (tmp_path / "o").exists()
    assert sorted(os.listdir(tmp_path)) == ["g.npz", "scheduler.json"]


def test_same_output_with_one_and_two_workers(processes, tmp_path):
    address, start_worker, _ = processes
    path = _big_input(tmp_path, 2400)
    start_worker()
    tables = []
    with dask_client(address) as dask:
        for workers in (1, 2):
            dask.wait_for_workers(workers, timeout=60)
            assert len(dask.scheduler_info()["workers"]) == workers
            run(_plan([path], chunk=300), tmp_path / f"out{workers}", dask, progress=False)
            tables.append(pq.read_table(tmp_path / f"out{workers}"))
            start_worker()
    one, two = tables
    assert one.num_rows == 2400 and one.schema.equals(two.schema)
    for key in ("id", "force_closure", "status", "status_name"):
        assert one[key].equals(two[key]), key
    # Bit for bit, margins included (Arrow's equals would call NaN unequal to itself).
    assert np.array_equal(one["margin"].to_numpy(), two["margin"].to_numpy(), equal_nan=True)
