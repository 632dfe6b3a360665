"""Output to object storage (S3 API) through fsspec, against a moto server on loopback."""

import json
import os
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest
import xarray as xr

from service.run import execute, render_batch, task_batches
from service.store import create_store
from service.sweep import parse_sweep

boto3 = pytest.importorskip("boto3")
pytest.importorskip("s3fs")

ROOT = Path(__file__).resolve().parent.parent
BIN = Path(sys.executable).parent

SWEEP = """\
name: s3
seed: 9
realisations: 3
output: s3://oceanlidar/run.zarr
scene:
  surface: {grid_size: 32, spacing: 0.1}
  receiver: {pixels: 16, gates: [[2.0, 6.0]]}
  noise: {photons: 100}
sweep:
  parameters:
    target.shape: {values: [sphere, none]}
"""


@pytest.fixture(scope="module")
def s3(tmp_path_factory):
    """A moto S3 server on 127.0.0.1 with an empty bucket; yields fsspec storage options."""
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port = probe.getsockname()[1]
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


def same_samples(a, b, storage_options):
    x = xr.open_zarr(a, storage_options=storage_options)
    y = xr.open_zarr(b)
    for name in ("image", "expected", "target_mask", "target_visibility", "completed"):
        assert x[name].values.tobytes() == y[name].values.tobytes(), name


def test_a_sweep_to_s3_resumes_to_the_bytes_of_a_local_run(s3, tmp_path):
    plan = parse_sweep(SWEEP)
    url = "s3://oceanlidar/run.zarr"
    # a first run that stopped after two samples, as a worker leaves it
    create_store(plan, url, storage_options=s3)
    start, jobs = next(task_batches(plan, range(plan.samples), 2))
    render_batch(url, start, jobs, s3)
    sweep = tmp_path / "s3.yaml"
    sweep.write_text(SWEEP)
    result = subprocess.run(
        [
            sys.executable,
            "-m",
            "service.cli",
            "run",
            str(sweep),
            "--resume",
            "--workers",
            "1",
            "--storage-options",
            json.dumps(s3),
        ],
        cwd=tmp_path,
        env={**os.environ, "PYTHONPATH": str(ROOT)},
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert result.returncode == 0, result.stderr
    assert "2 already complete" in result.stderr
    local = str(tmp_path / "local.zarr")
    execute(plan, local, workers=1, progress_stream=open(os.devnull, "w"))
    same_samples(url, local, s3)
    stats = xr.open_zarr("s3://oceanlidar/run.stats.zarr", storage_options=s3)
    assert stats["samples"].values.tolist() == [3, 3]
