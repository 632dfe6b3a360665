"""Shared test helpers."""

import contextlib
import os
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
import xarray as xr

from workers.setup.geometry import LaserRays, PlaneGrid


def ring_around(mask, width):
    """Pixels within `width` (Chebyshev distance) of `mask` (y, x), outside it: brute force."""
    y, x = np.mgrid[: mask.shape[0], : mask.shape[1]]
    near = np.zeros(mask.shape, bool)
    for r, c in zip(*np.nonzero(mask), strict=True):
        near |= (abs(y - r) <= width) & (abs(x - c) <= width)
    return near & ~mask


def plane_grid(camera, *, depth, refractive_index=1.34, guard=4):
    """The renderer's plane grid for `camera` lit by the default (matching) laser."""
    lattice = LaserRays.central(
        position=camera.position,
        rotation=camera.rotation,
        beam="divergent",
        field_of_view=camera.field_of_view,
        rays=camera.pixels,
        reference_range=camera.position[2],
    )
    return PlaneGrid.covering(
        camera=camera,
        lattice=lattice,
        depth=depth,
        refractive_index=refractive_index,
        guard=guard,
    )


ROOT = Path(__file__).resolve().parent.parent

TINY_SCENE = """\
name: {name}
seed: {seed}
realisations: {realisations}
output: {output}
scene:
  surface: {{grid_size: 32, spacing: 0.1, allow_repeat: true}}  # tiny: the sea repeats
  receiver: {{pixels: 16, gates: [[2.0, 6.0]]}}
  radiometry: {{mode: normalised, white_plane_photons: 100}}
"""
"""A sweep of tiny samples of the default scene alone (one parameter point)."""

TINY_SWEEP = (
    TINY_SCENE
    + """\
sweep:
  parameters:
    target.shape: {{values: [sphere, none]}}
"""
)
"""A sweep of tiny samples (a sphere and no target) for service tests."""


def cf_failures(dataset, path):
    """The CF-1.10 checks `dataset` fails once exported to netCDF at `path`: (name, messages)."""
    from compliance_checker.runner import CheckSuite

    dataset.to_netcdf(path)
    suite = CheckSuite()
    suite.load_all_available_checkers()
    results = suite.run_all(suite.load_dataset(str(path)), ["cf:1.10"], skip_checks=[])
    return [
        (result.name, result.msgs)
        for result in results["cf:1.10"][0]
        if result.value[0] < result.value[1]
    ]


def store_lock(store) -> Path:
    """The writer's lock file of the local store at `store` (beside it)."""
    from service.store.lock import lock_file

    return Path(lock_file(str(store)))


def free_port():
    """A TCP port free on 127.0.0.1 now."""
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


def cli_command(*args, env=None):
    """The command line and environment of `oceanlidar ARGS` in a fresh process."""
    command = [sys.executable, "-m", "service.cli", *map(str, args)]
    return command, {**os.environ, "PYTHONPATH": str(ROOT), **(env or {})}


def run_cli(*args, cwd, env=None, timeout=300):
    """Run `oceanlidar ARGS` as a user would, in a fresh process."""
    command, env = cli_command(*args, env=env)
    return subprocess.run(
        command, cwd=cwd, capture_output=True, text=True, env=env, timeout=timeout
    )


def start_cli(*args, cwd, env=None, **popen):
    """Start `oceanlidar ARGS` in a fresh process and return it (a `subprocess.Popen`).

    It starts as a terminal's foreground job does, with SIGINT at its default: a Ctrl-C
    raises KeyboardInterrupt in it. A process inherits an ignored signal, and a test
    process may ignore SIGINT: a suite started as a background job of a non-interactive
    shell (``pytest &`` in a script, as a CI runner may start it) has SIGINT ignored
    (POSIX), and so had every run it started, which a Ctrl-C then left running.
    """
    command, env = cli_command(*args, env=env)
    with sigint_default():
        return subprocess.Popen(command, cwd=cwd, env=env, **popen)


@contextlib.contextmanager
def sigint_default():
    """SIGINT handled (as Python's default) and unblocked here, so in the processes started.

    A handler set in Python is the system's default in a program it executes, while an
    ignored signal stays ignored, and a blocked one blocked (the starting thread's mask).
    Only the main thread sets handlers: elsewhere, nothing changes.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    blocked = signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})
    try:
        yield
    finally:  # None: a handler not set from Python, the system's default
        signal.pthread_sigmask(signal.SIG_SETMASK, blocked)
        signal.signal(signal.SIGINT, signal.SIG_DFL if previous is None else previous)


def ended(process, timeout=120):
    """The output of `process` (``out, err``), once it ends within `timeout` s.

    Else it is killed with its process group (started with ``start_new_session``) and the
    test fails with what it had written: no run is left holding its tasks behind.
    """
    try:
        return process.communicate(timeout=timeout)
    except subprocess.TimeoutExpired:
        os.killpg(process.pid, signal.SIGKILL)
        _, err = process.communicate()
        pytest.fail(f"the run had not ended {timeout} s after the signal; it wrote:\n{err}")


def holding(folder, shards, *, busy=False):
    """The environment of a run whose tasks hold once `shards` shards are written.

    `service.cluster.hold`: each task marks its written shard in `folder`; from the
    `shards`-th on, they wait until the run is interrupted (the interrupt tests signal a
    run at that point, not at a time), or if `busy` for `service.cluster.HOLD_LIMIT`
    whatever happens (a sample mid-render, which no cancel stops).
    """
    from service.cluster import HOLD

    folder.mkdir()
    (folder / "hold").write_text(str(shards))
    if busy:
        (folder / "busy").touch()
    return {HOLD: str(folder)}


def wait_for_shards(folder, shards, process, timeout=120):
    """Wait until `shards` shards of the run `process` (held in `folder`) are written."""
    deadline = time.monotonic() + timeout
    while len(list(folder.glob("shard-*"))) < shards:
        assert process.poll() is None, "the run ended before its tasks held"
        assert time.monotonic() < deadline, f"fewer than {shards} shards in {timeout} s"
        time.sleep(0.05)


@pytest.fixture
def cli(capsys, monkeypatch):
    """`run_cli` in this process: `service.cli.main`, its output read by `capsys`.

    For what needs no process of its own (bad input, `validate`, a run on the session's
    cluster with `shared_cluster`); returns a `subprocess.CompletedProcess` as `run_cli`.
    """
    from service.cli import main

    def run(*args, cwd, env=None):
        capsys.readouterr()  # what came before is not this command's
        with monkeypatch.context() as patch:
            patch.chdir(cwd)
            for name, value in (env or {}).items():
                patch.setenv(name, str(value))
            try:
                code = main([str(arg) for arg in args])
            except SystemExit as exit:  # argparse's own status
                code = exit.code
        out, err = capsys.readouterr()
        return subprocess.CompletedProcess(list(args), code, out, err)

    return run


@pytest.fixture(scope="session")
def session_cluster():
    """The session's one embedded dask cluster (two workers) and its client.

    Started as `oceanlidar run` starts its own (`service.cluster.embedded_cluster`), for the
    tests that only need a cluster. Not the default client: tests reach it through
    `on_cluster` (or `execute(client=...)`).
    """
    from distributed import Client

    from service.cluster import WarningsToLogging, embedded_cluster

    with embedded_cluster(workers=2) as cluster:
        client = Client(cluster, set_as_default=False)
        try:
            client.register_plugin(WarningsToLogging(False))
            yield client
        finally:
            client.close()


@contextlib.contextmanager
def on_cluster(client):
    """Runs (`service.run.execute`, `oceanlidar run` in this process) on `client`.

    Instead of an embedded cluster of their own: `client` is the current one for the
    run, as the embedded cluster's is.
    """
    import service.run

    @contextlib.contextmanager
    def connect(**_):
        with client.as_current():
            yield client

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(service.run, "dask_client", connect)
        yield client


@pytest.fixture
def shared_cluster(session_cluster):
    """This test's runs on the session's cluster (`on_cluster`)."""
    with on_cluster(session_cluster):
        yield session_cluster


SAMPLE_VARIABLES = (
    "image",
    "target_mask",
    "target_signal",
    "background_signal",
    "target_visibility",
    "completed",
)


def assert_same_samples(a, b, *, storage_options=None, names=SAMPLE_VARIABLES):
    """Two stores hold byte-identical samples (and completion records).

    `names`: the variables compared; None compares every variable of `a`.
    """
    x = xr.open_zarr(a, storage_options=storage_options)
    y = xr.open_zarr(b)
    for name in x.variables if names is None else names:
        assert same_values(x[name].values, y[name].values), name


def same_values(a, b):
    """Two arrays are equal: numbers bit for bit (NaNs included), strings as text.

    A string array's bytes are not its text: an object array holds pointers, numpy's
    StringDType offsets into its own buffer; which of the two a store's strings read as
    depends on the zarr and numpy versions.
    """
    if a.dtype.kind in "OTUS" or b.dtype.kind in "OTUS":
        return a.shape == b.shape and a.tolist() == b.tolist()
    return a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()


@contextlib.contextmanager
def dask_processes(folder, *, workers=2, protocol="tcp", options=(), env=None):
    """`dask scheduler` and `dask worker` processes on 127.0.0.1 only (HTTP servers too).

    Yields the scheduler address. The processes are terminated, then killed if they linger,
    whatever happens in the test.
    """
    port = free_port()
    address = f"{protocol}://127.0.0.1:{port}"
    environment = {**os.environ, **(env or {})}
    loopback = ["--host", "127.0.0.1", "--no-dashboard", "--dashboard-address", "127.0.0.1:0"]
    dask = str(Path(sys.executable).parent / "dask")
    processes = [
        subprocess.Popen(
            [dask, "scheduler", "--protocol", protocol, "--port", str(port), *loopback, *options],
            cwd=folder,
            env=environment,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
        )
    ]
    try:
        processes += [
            subprocess.Popen(
                [dask, "worker", address, "--nthreads", "1", *loopback, *options],
                cwd=folder,
                env=environment,
                stdout=subprocess.DEVNULL,
                stderr=subprocess.DEVNULL,
            )
            for _ in range(workers)
        ]
        yield address
    finally:
        # the workers, then the scheduler: a worker whose scheduler has gone first takes
        # seconds to leave
        for group in (processes[1:], processes[:1]):
            for process in group:
                process.terminate()
            for process in group:
                try:
                    process.wait(timeout=10)
                except subprocess.TimeoutExpired:
                    process.kill()
                    process.wait(timeout=10)


def batch_of(render):
    """A stand-in for `service.tasks.render_samples` that renders each seed by `render`.

    `render(scene, *, seed)` returns one sample's arrays (as `workers.render.render_arrays`):
    the tests that poison, freeze or break one sample of a task's batch.
    """

    def render_samples(scene, seeds, *, backend):
        samples = [render(scene, seed=seed) for seed in seeds]
        return {name: np.stack([sample[name] for sample in samples]) for name in samples[0]}

    return render_samples


@pytest.fixture
def threads(monkeypatch):
    """The embedded cluster's workers as threads of this process, to see monkeypatches."""
    from distributed import LocalCluster

    import service.cluster
    import service.run

    def threaded(*, config=None, **options):
        # threads read this process's configuration: a nanny's `config` has no worker here
        return LocalCluster(**{**options, "processes": False, "protocol": "tcp://"})

    monkeypatch.setattr(service.cluster, "LocalCluster", threaded)
    return service.run
