"""Runs on a separately started dask cluster (loopback only): same bytes, faults reported."""

import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
import xarray as xr
from conftest import ROOT, TINY_SWEEP, assert_same_samples, dask_processes, start_cli
from distributed import Client
from distributed.diagnostics.plugin import WorkerPlugin

from service.run import execute, run_plan
from service.store.location import Store
from service.store.template import create_store
from service.sweep import parse_sweep

BIN = Path(sys.executable).parent


def sweep_text(realisations=3):
    return TINY_SWEEP.format(name="cluster", seed=5, realisations=realisations, output="c.zarr")


SWEEP = sweep_text()


@pytest.fixture(scope="module")
def cluster(tmp_path_factory):
    """`dask scheduler` and two `dask worker` processes, on 127.0.0.1 only."""
    # workers import this module too (the crash plugin below)
    path = os.pathsep.join([str(ROOT), str(ROOT / "tests")])
    with dask_processes(tmp_path_factory.mktemp("cluster"), env={"PYTHONPATH": path}) as address:
        with Client(address, timeout="60s") as client:
            client.wait_for_workers(2, timeout=60)
        yield address


def test_run_on_an_external_scheduler_writes_the_embedded_bytes(cluster, tmp_path, cli):
    sweep = tmp_path / "s.yaml"
    sweep.write_text(SWEEP)
    for name, extra in (("external", ["--scheduler", cluster]), ("embedded", ["--workers", "1"])):
        output = tmp_path / f"{name}.zarr"
        result = cli("run", sweep, "--output", output, "--batch", 1, *extra, cwd=tmp_path)
        assert result.returncode == 0, result.stderr
    assert_same_samples(tmp_path / "external.zarr", tmp_path / "embedded.zarr", names=None)


class CrashOnSample(WorkerPlugin):
    """Kill the worker process whenever it starts the task of one sample."""

    def __init__(self, sample):
        self.sample = sample

    def setup(self, worker):
        self.worker = worker

    def transition(self, key, start, finish, **kwargs):
        if finish == "executing" and str(key).endswith(f"-{self.sample}-1"):
            os._exit(1)


def test_a_sample_that_kills_its_worker_is_reported_and_the_rest_complete(cluster, tmp_path):
    plan = parse_sweep(SWEEP)
    url = str(tmp_path / "crash.zarr")
    create_store(plan, Store(url), samples_per_shard=1)
    with Client(cluster, timeout="60s") as client:
        client.register_plugin(CrashOnSample(4), name="crash-on-sample-4")
        try:
            result = run_plan(
                plan, Store(url), client=client, progress_stream=open(os.devnull, "w")
            )
        finally:
            client.unregister_worker_plugin("crash-on-sample-4")
        client.wait_for_workers(2, timeout=120)
    assert [(start, count) for start, count, _ in result.failed] == [(4, 1)]
    assert "KilledWorker" in result.failed[0][2]
    done = xr.open_zarr(url)["completed"].values
    assert done.tolist() == [1, 1, 1, 1, 0, 1]
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:  # the nannies restart the killed workers
        with Client(cluster, timeout="30s") as client:
            if len(client.scheduler_info()["workers"]) == 2:
                break
        time.sleep(1)


def test_a_worker_killed_mid_sweep_changes_no_byte(cluster, tmp_path, shared_cluster):
    plan = parse_sweep(sweep_text(realisations=8))
    url = str(tmp_path / "killed.zarr")
    create_store(plan, Store(url), samples_per_shard=1)
    with Client(cluster, timeout="60s") as client:
        victim = next(iter(client.run(os.getpid).values()))

        def kill_when_started():
            deadline = time.monotonic() + 60
            while time.monotonic() < deadline:
                if xr.open_zarr(url)["completed"].values.sum() >= 2:
                    os.kill(victim, signal.SIGKILL)
                    return
                time.sleep(0.02)

        killer = threading.Thread(target=kill_when_started)
        killer.start()
        result = run_plan(plan, Store(url), client=client, progress_stream=open(os.devnull, "w"))
        killer.join()
        client.wait_for_workers(2, timeout=120)
    assert result.failed == [] and result.written == plan.samples
    reference = str(tmp_path / "undisturbed.zarr")
    execute(plan, Store.at(reference), workers=1, progress_stream=open(os.devnull, "w"))
    assert_same_samples(url, reference)


def test_a_killed_client_resumes_to_the_same_bytes(cluster, tmp_path, cli, shared_cluster):
    sweep = tmp_path / "s.yaml"
    sweep.write_text(sweep_text(realisations=30))  # 60 tasks: most still to run at the kill
    target = tmp_path / "client.zarr"
    command = ["run", sweep, "--output", target, "--scheduler", cluster, "--batch", 1]
    process = start_cli(
        *command, cwd=tmp_path, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL
    )
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and process.poll() is None:
        try:
            if xr.open_zarr(target, consolidated=False)["completed"].values.sum() >= 2:
                break
        except Exception:  # not created yet
            pass
        time.sleep(0.02)
    process.send_signal(signal.SIGKILL)
    process.wait(timeout=30)
    assert 0 < xr.open_zarr(target)["completed"].values.sum() < 60
    again = cli(*command, "--resume", cwd=tmp_path)
    assert again.returncode == 0, again.stderr
    reference = str(tmp_path / "reference.zarr")
    execute(
        parse_sweep(sweep.read_text()),
        Store.at(reference),
        workers=1,
        progress_stream=open(os.devnull, "w"),
    )
    assert_same_samples(str(target), reference)


def test_the_started_cluster_listens_on_loopback_only(cluster):
    import psutil

    addresses = {
        connection.laddr.ip
        for process in psutil.Process().children(recursive=True)
        for connection in process.net_connections(kind="inet")
        if connection.status == psutil.CONN_LISTEN
    }
    assert addresses == {"127.0.0.1"}
