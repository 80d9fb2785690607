"""grasp-fc-label across three hosts (network namespaces, test/net_hosts.py): a Dask
scheduler and the labeller on one, a worker on each of the two others; one worker host
loses its link and its processes mid-run. Skipped where network namespaces cannot be made
(not root, no ``ip``). Its long form: ``benchmarks/bench_label.py --hosts``."""

import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest

import net_hosts
from grasp_fc_ros.labelling import open_input
from grasp_fc_ros.labelling.tasks import label_chunk
from grasp_fc_ros.objects import make_object, sample_grasps
from waiting import wait_for

BIN = Path(sys.executable).parent
REASON = net_hosts.unavailable()
needs_namespaces = pytest.mark.skipif(REASON is not None,
                                      reason=f"no network namespaces: {REASON}")

# 40 chunks of six-finger grasps: a few seconds of work per worker here, long enough
# for the cut to come with chunks still queued on the lost host.
N_GRASPS = 120_000
CHUNK = 3_000
WORKER_HOSTS = (1, 2)
LOST = 2


def test_the_reason_namespaces_cannot_be_made_is_given(monkeypatch):
    monkeypatch.setattr(net_hosts.os, "geteuid", lambda: 1000)
    assert net_hosts.unavailable().startswith("not root")
    monkeypatch.setattr(net_hosts.shutil, "which", lambda name: None)
    assert net_hosts.unavailable() == "no `ip` command (iproute2) on PATH"


def _namespaces():
    listing = subprocess.run(["ip", "netns", "list"], capture_output=True, text=True,
                             check=True).stdout
    return {line.split()[0] for line in listing.splitlines()}


@needs_namespaces
def test_hosts_are_separate_and_removed_even_on_failure(tmp_path):
    with pytest.raises(RuntimeError, match="inside"):  # noqa: PT012
        with net_hosts.Hosts(2, tmp_path) as hosts:
            made = {*hosts.namespaces, hosts.switch}
            assert made <= _namespaces()
            listen = ("import socket, time\ns = socket.create_server(('', 7000))\n"
                      "print('up', flush=True)\nc, (peer, _) = s.accept()\n"
                      "print(peer, flush=True)\ntime.sleep(60)\n")
            server = hosts.popen(1, [sys.executable, "-c", listen], stdout=subprocess.PIPE)
            assert server.stdout.readline() == b"up\n"
            connect = [sys.executable, "-c", "import socket; socket.create_connection("
                       f"('{hosts.address(1)}', 7000), timeout=5)"]
            assert hosts.popen(0, connect).wait(timeout=30) == 0
            # host 1 saw host 0's address: they are joined by the bridge, not the root
            assert server.stdout.readline().decode().strip() == hosts.address(0)
            raise RuntimeError("a failure inside")
    assert not made & _namespaces()
    assert server.poll() is not None


@needs_namespaces
def test_namespaces_of_a_killed_run_are_swept(tmp_path):
    gone = subprocess.Popen(["true"])
    gone.wait()
    stale = f"{net_hosts.PREFIX}{gone.pid}-dead00-h0"
    subprocess.run(["ip", "netns", "add", stale], check=True)
    try:
        assert stale in net_hosts.sweep_stale()
        assert stale not in _namespaces()
    finally:
        subprocess.run(["ip", "netns", "del", stale], capture_output=True)


def _one_process_labels(path, chunk):
    """The labels of a run in one process: label_chunk over the same chunks."""
    source = open_input(path)
    return pa.concat_tables(label_chunk(source, start, min(start + chunk, source.n_grasps),
                                        "auto", "seed")
                            for start in range(0, source.n_grasps, chunk))


@needs_namespaces
def test_worker_host_cut_mid_run_loses_nothing(tmp_path):
    p, n = sample_grasps(make_object("box", n_points=2000), N_GRASPS, 6,
                         np.random.default_rng(5))
    path = tmp_path / "grasps.npz"
    np.savez(path, positions=p, normals=n, mu=0.5)
    out = tmp_path / "out"
    env = net_hosts.dask_environment(net_hosts.FAST_LOSS_CONFIG)
    with net_hosts.Hosts(3, tmp_path / "hosts") as hosts:
        address = net_hosts.start_dask(hosts, BIN / "dask", WORKER_HOSTS, env)
        scheduler = hosts.processes[0][1]
        watcher = net_hosts.Watcher(hosts, sys.executable, address)
        labeller = hosts.popen(0, [str(BIN / "grasp-fc-label"), str(path), "--out", str(out),
                                   "--chunk-size", str(CHUNK), "--scheduler", address],
                               env=env)
        lost = f"tcp://{hosts.address(LOST)}:"

        def lost_host_busy():  # it has chunks to lose (or the run is over: fails below)
            busy = watcher.processing()
            return any(w.startswith(lost) and k for w, k in busy.items()) and any(
                out.glob("part-*")) or labeller.poll() is not None

        wait_for(lost_host_busy, 120, "a part written and chunks on the lost host")
        cut_at = time.time()
        hosts.cut(LOST)
        parts_at_cut = len(list(out.glob("part-*")))
        labeller.wait(timeout=300)
        report = hosts.log(labeller)
        scheduler_log = hosts.log(scheduler)

    assert labeller.returncode == 0, report
    n_chunks = N_GRASPS // CHUNK
    assert parts_at_cut < n_chunks  # the cut came mid-run
    assert f"{N_GRASPS:,} grasps labelled in {n_chunks} chunk(s)" in report
    # The lost worker was removed, and only it: busy workers kept heartbeating.
    removed = [line for line in scheduler_log.splitlines() if "Remove worker addr:" in line]
    assert len(removed) == 1 and f"Remove worker addr: {lost}" in removed[0], removed
    print(f"cut at {cut_at:.1f} with {parts_at_cut}/{n_chunks} parts written")
    table = pq.read_table(out)
    # Every row once, in order, and equal to a one-process run, margins bit for bit.
    assert np.array_equal(table["id"].to_numpy(), np.arange(N_GRASPS))
    expected = _one_process_labels(path, CHUNK)
    assert table.schema.equals(expected.schema)
    for key in ("id", "force_closure", "status", "status_name"):
        assert table[key].equals(expected[key]), key
    assert np.array_equal(table["margin"].to_numpy(), expected["margin"].to_numpy(),
                          equal_nan=True)
