"""Output to object storage (S3 API) through fsspec, against a moto server on loopback."""

import json
import os
import subprocess
import sys
import time
from pathlib import Path

import fsspec
import pytest
import xarray as xr
from conftest import TINY_SWEEP, assert_same_samples, free_port

from service.run import execute, render_shard, task_batches
from service.store.location import Store
from service.store.template import create_store
from service.sweep import parse_sweep

boto3 = pytest.importorskip("boto3")
pytest.importorskip("s3fs")

BIN = Path(sys.executable).parent

SWEEP_URL = "s3://oceanlidar/run.zarr"
SWEEP = TINY_SWEEP.format(name="s3", seed=9, realisations=3, output=SWEEP_URL)


@pytest.fixture(scope="module")
def s3(tmp_path_factory):
    """A moto S3 server on 127.0.0.1 with an empty bucket; yields fsspec storage options."""
    port = free_port()
    server = subprocess.Popen(
        [str(BIN / "moto_server"), "-H", "127.0.0.1", "-p", str(port)],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )
    endpoint = f"http://127.0.0.1:{port}"
    client = boto3.client(
        "s3",
        endpoint_url=endpoint,
        aws_access_key_id="test",
        aws_secret_access_key="test",
        region_name="us-east-1",
    )
    deadline = time.monotonic() + 30
    while True:
        try:
            client.create_bucket(Bucket="oceanlidar")
            break
        except Exception:
            if time.monotonic() > deadline:
                server.terminate()
                raise
            time.sleep(0.2)
    try:
        yield {
            "key": "test",
            "secret": "test",
            "client_kwargs": {"endpoint_url": endpoint, "region_name": "us-east-1"},
        }
    finally:
        server.terminate()
        server.wait(timeout=30)


def test_a_sweep_to_s3_resumes_to_the_bytes_of_a_local_run(s3, tmp_path, cli, shared_cluster):
    plan = parse_sweep(SWEEP)
    url = "s3://oceanlidar/run.zarr"
    # a first run that stopped after its first shard of two samples, as a worker leaves it
    create_store(plan, Store(url, s3), samples_per_shard=2)
    _, jobs = next(task_batches(plan, range(plan.samples), 2))
    render_shard(Store(url, s3), jobs)
    sweep = tmp_path / "s3.yaml"
    sweep.write_text(SWEEP)
    options = json.dumps(s3)
    result = cli(
        "run", sweep, "--resume", "--workers", 1, "--storage-options", options, cwd=tmp_path
    )
    assert result.returncode == 0, result.stderr
    assert "2 already complete" in result.stderr
    local = str(tmp_path / "local.zarr")
    execute(plan, Store.at(local), workers=1, progress_stream=open(os.devnull, "w"))
    assert_same_samples(url, local, storage_options=s3)
    stats = xr.open_zarr("s3://oceanlidar/run.stats.zarr", storage_options=s3)
    assert stats["samples"].values.tolist() == [3, 3]
    # the run's lock is gone, and the statistics were moved into place whole
    fs = fsspec.filesystem("s3", **s3)
    assert fs.find("oceanlidar/run.zarr.lock") == []
    assert [path for path in fs.ls("oceanlidar") if "partial" in path] == []


def test_a_second_writer_is_refused_on_object_storage(s3, tmp_path, capsys):
    from service.cli import main
    from service.store.lock import lock_file

    url = "s3://oceanlidar/locked.zarr"
    sweep = tmp_path / "s3.yaml"
    sweep.write_text(SWEEP)
    fs = fsspec.filesystem("s3", **s3)
    with Store(url, s3).lock():
        assert fs.exists(lock_file("oceanlidar/locked.zarr"))
        command = ["run", str(sweep), "--output", url, "--storage-options", json.dumps(s3)]
        assert main(command) == 2
    err = capsys.readouterr().err
    assert "locked by another run" in err and "Traceback" not in err
    fs.invalidate_cache()
    assert not fs.exists("oceanlidar/locked.zarr")


def test_unreachable_storage_is_refused_before_rendering(s3, tmp_path, capsys):
    from service.cli import main

    sweep = tmp_path / "s3.yaml"
    sweep.write_text(SWEEP)
    unreachable = {
        **s3,
        "client_kwargs": {"endpoint_url": f"http://127.0.0.1:{free_port()}"},
        "config_kwargs": {"connect_timeout": 1, "retries": {"max_attempts": 1}},
    }
    for url, options in (("s3://no-such-bucket/run.zarr", s3), (SWEEP_URL, unreachable)):
        command = ["run", str(sweep), "--output", url, "--storage-options", json.dumps(options)]
        assert main(command) == 2
        err = capsys.readouterr().err
        assert f"'{url}' cannot be written" in err and "Traceback" not in err
