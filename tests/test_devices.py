"""Where a run renders (issue #28, items 3, 5, 6): --backend and --device in the service."""

import contextlib
import importlib.machinery
import importlib.util
import re
import sys
import threading
import tomllib
import types

import numpy as np
import pytest
import xarray as xr
from conftest import ROOT, TINY_SWEEP, assert_same_samples, store_lock

import service.cluster
import service.run
import service.tasks
from service.admission import admit_job
from service.cluster import GPU_TASKS, dask_client
from service.devices import NUMPY, choose, stored
from service.errors import BadOptionError, UnusableOutputError
from service.run import execute, render_shard, task_batches
from service.store.location import Store
from service.sweep import parse_sweep
from workers.backends.backend import Backend, get_backend

TORCH_CPU = Backend(name="torch", device="cpu")


def cuda_here():
    """Whether this machine renders on CUDA (torch sees a GPU)."""
    if importlib.util.find_spec("torch") is None:
        return False
    import torch

    return torch.cuda.is_available()


def sweep_file(folder, *, realisations=2, name="devices"):
    path = folder / "sweep.yaml"
    path.write_text(
        TINY_SWEEP.format(name=name, seed=3, realisations=realisations, output="out.zarr")
    )
    return path


@pytest.fixture
def work(tmp_path):
    sweep_file(tmp_path)
    return tmp_path


NO_RENDER_HERE = [
    pytest.param(
        ["--backend", "numpy", "--device", "cuda"],
        "--device: the numpy backend runs on the cpu",
        id="numpy-on-cuda",
    ),
    pytest.param(
        ["--device", "tpu"], "--device: 'tpu' is neither 'cpu' nor 'cuda'", id="unknown-device"
    ),
    pytest.param(["--device", ""], "--device: '' is neither 'cpu' nor 'cuda'", id="no-device"),
    pytest.param(
        ["--backend", "torch"],
        "--backend: torch is not installed here (pip install 'oceanlidar[train]' for the CPU",
        id="no-torch",
    ),
]
if not cuda_here():
    NO_RENDER_HERE.append(
        pytest.param(
            ["--device", "cuda"],
            "--device: 'cuda' asked, but this machine has no CUDA device",
            id="no-cuda",
        )
    )


@pytest.fixture
def without_torch(monkeypatch):
    """This process sees no torch (`workers.backends.backend.get_backend` looks it up afresh)."""
    real = importlib.util.find_spec
    monkeypatch.setattr(
        importlib.util, "find_spec", lambda name, *a: None if name == "torch" else real(name, *a)
    )
    get_backend.cache_clear()
    yield
    get_backend.cache_clear()


@pytest.mark.parametrize("command", ["run", "validate", "validate-quick", "serve"])
@pytest.mark.parametrize(("flags", "message"), NO_RENDER_HERE)
def test_a_backend_that_cannot_render_here_is_refused_before_anything_is_written(
    work, cli, command, flags, message, request
):
    # issue #28 item 5: checked by workers.backends.backend.get_backend up front, the flag named,
    # exit
    # 2, no traceback, nothing written (no store, no lock; serve: no job table, no data root)
    if "no-torch" in request.node.callspec.id:
        request.getfixturevalue("without_torch")
    args = {
        "run": ["run", "sweep.yaml"],
        "validate": ["validate", "sweep.yaml"],
        "validate-quick": ["validate", "sweep.yaml", "--no-estimate"],  # a trial's find
        "serve": [
            "serve",
            "--no-auth",
            "--port",
            "1",
            "--db",
            "jobs.sqlite",
            "--data-root",
            "data",
        ],
    }[command]
    result = cli(*args, *flags, cwd=work)
    assert result.returncode == 2, result.stderr
    assert f"oceanlidar {command.split('-')[0]}: error: {message}" in result.stderr
    assert "Traceback" not in result.stderr
    assert sorted(p.name for p in work.iterdir()) == ["sweep.yaml"]


@pytest.mark.parametrize("command", ["run", "validate"])
def test_monte_carlo_points_on_torch_are_refused_before_anything_is_written(work, cli, command):
    # found by a trial: the run wrote the fast points, refused the Monte Carlo ones one by
    # one, and left a half store that only --overwrite could reuse
    sweep = work / "sweep.yaml"
    sweep.write_text(
        sweep.read_text().replace(
            "target.shape: {values: [sphere, none]}",
            "transport.method: {values: [small_angle, monte_carlo]}",
        )
    )
    extra = ["--no-estimate"] if command == "validate" else []
    result = cli(command, "sweep.yaml", "--backend", "torch", *extra, cwd=work)
    assert result.returncode == 2, result.stderr
    assert (
        "--backend torch: point 1 renders by Monte Carlo (transport.method: monte_carlo), "
        "which runs on the numpy backend only"
    ) in result.stderr
    assert "Traceback" not in result.stderr
    assert sorted(p.name for p in work.iterdir()) == ["sweep.yaml"]


def test_the_flags_choose_numpy_on_the_cpu_and_torch_on_a_gpu():
    assert choose(None, None) == NUMPY
    assert choose("torch", None) == TORCH_CPU
    assert choose(None, "cuda", here=False) == Backend(name="torch", device="cuda")
    with pytest.raises(BadOptionError, match="--device cuda:1: a scheduler's GPU workers"):
        choose(None, "cuda:1", here=False)
    assert stored({}) == {"render_backend": "numpy", "render_device": "cpu"}  # older stores


@pytest.fixture(scope="module")
def numpy_store(tmp_path_factory, session_cluster):
    """A store of the tiny sweep rendered on numpy (the default), its folder."""
    from conftest import on_cluster

    from service.cli import main

    folder = tmp_path_factory.mktemp("numpy")
    sweep_file(folder)
    with on_cluster(session_cluster), contextlib.chdir(folder):
        assert main(["run", "sweep.yaml", "--batch", "2"]) == 0
    return folder


def test_the_store_records_where_it_was_rendered_and_info_says_it(numpy_store, cli, tmp_path):
    # issue #28 item 3: the store records its backend and device (root attributes)
    with xr.open_zarr(numpy_store / "out.zarr") as ds:
        assert (ds.attrs["render_backend"], ds.attrs["render_device"]) == ("numpy", "cpu")
    info = cli("info", numpy_store / "out.zarr", cwd=tmp_path)
    assert "  rendered on: backend numpy, device cpu\n" in info.stdout


def test_a_resume_on_another_backend_is_refused_naming_both(numpy_store, cli, shared_cluster):
    # issue #28 item 3: --resume refuses to mix backends or devices; nothing is touched
    store = numpy_store / "out.zarr"
    before = {p: p.stat().st_mtime_ns for p in store.rglob("*")}
    result = cli("run", "sweep.yaml", "--resume", "--backend", "torch", cwd=numpy_store)
    assert result.returncode == 2, result.stderr
    assert (
        f"{store} was rendered with --backend numpy --device cpu, this run renders with "
        "--backend torch --device cpu: its samples would differ; resume with --backend "
        "numpy --device cpu or start again with --overwrite"
    ) in result.stderr
    assert {p: p.stat().st_mtime_ns for p in store.rglob("*")} == before
    assert not store_lock(store).exists()
    # the job service alike (its backend is `serve`'s): the job is rejected
    text = (numpy_store / "sweep.yaml").read_text()
    with pytest.raises(UnusableOutputError, match="--backend numpy --device cpu, this run"):
        admit_job(text, "resume", data_root=Store.at(str(numpy_store)), backend=TORCH_CPU)
    admit_job(text, "resume", data_root=Store.at(str(numpy_store)), backend=NUMPY)


def test_a_shards_samples_of_one_scene_render_in_one_batch_on_the_runs_backend(
    tmp_path, monkeypatch
):
    # issue #28 item 5: a task renders its shard in one batch (one per scene it holds), on
    # the run's backend, and writes what a render of each sample alone gives
    from workers.render import render_arrays

    sweep_file(tmp_path, realisations=3)
    plan = parse_sweep((tmp_path / "sweep.yaml").read_text(), folder=tmp_path)
    store = Store.at(str(tmp_path / "out.zarr"))
    from service.store.template import create_store

    create_store(plan, store, samples_per_shard=4, backend=TORCH_CPU)
    batches = []
    real = service.tasks.render_samples

    def spy(scene, seeds, *, backend):
        batches.append((scene, len(seeds), backend))
        return real(scene, seeds, backend=NUMPY)

    monkeypatch.setattr(service.tasks, "render_samples", spy)
    for _, jobs in task_batches(plan, range(plan.samples), 4):
        assert render_shard(store, jobs, TORCH_CPU) == []
    scenes = plan.scenes
    assert batches == [
        (scenes[0], 3, TORCH_CPU),  # shard 0: point 0's three samples, then point 1's first
        (scenes[1], 1, TORCH_CPU),
        (scenes[1], 2, TORCH_CPU),  # shard 1
    ]
    with xr.open_zarr(store.url) as ds:
        for sample in (0, 3, 5):
            alone = render_arrays(plan.sample(sample).scene, seed=plan.sample(sample).seed)
            assert ds.image[sample].values.tobytes() == alone["image"].tobytes()


def test_a_shards_samples_of_a_scene_render_in_batches_that_fit_the_memory_given(tmp_path):
    # issue #39 item 5: a task renders a scene's samples in batches of as many as fit its
    # memory budget (`service.batching.batch_samples`, at least one), and the bytes are
    # those of one batch a scene: a sample's bytes never depend on its batch
    from service.batching import sample_memory
    from service.store.template import create_store

    sweep_file(tmp_path, realisations=3)
    plan = parse_sweep((tmp_path / "sweep.yaml").read_text(), folder=tmp_path)
    per_sample = max(sample_memory(scene) for scene in plan.scenes)
    batches = []
    real = service.tasks.render_samples

    def spy(scene, seeds, *, backend):
        batches.append((plan.scenes.index(scene), len(seeds)))
        return real(scene, seeds, backend=backend)

    stores = {}
    for memory in (None, 2.5 * per_sample, 0.5 * per_sample):
        store = stores[memory] = Store.at(str(tmp_path / f"out-{memory}.zarr"))
        create_store(plan, store, samples_per_shard=4)
        batches.clear()
        with pytest.MonkeyPatch.context() as patch:
            patch.setattr(service.tasks, "render_samples", spy)
            for _, jobs in task_batches(plan, range(plan.samples), 4):
                assert render_shard(store, jobs, NUMPY, memory) == []
        stores[memory] = (store, list(batches))
    # shard 0 holds point 0's three samples and point 1's first, shard 1 point 1's others
    assert stores[None][1] == [(0, 3), (1, 1), (1, 2)]  # this machine's budget: all at once
    assert stores[2.5 * per_sample][1] == [(0, 2), (0, 1), (1, 1), (1, 2)]
    assert stores[0.5 * per_sample][1] == [(0, 1)] * 3 + [(1, 1)] * 3  # one a batch, at least
    whole = stores[None][0].url
    for memory in (2.5 * per_sample, 0.5 * per_sample):
        assert_same_samples(stores[memory][0].url, whole, names=None)


def test_a_runs_batch_memory_reaches_its_tasks(tmp_path, monkeypatch):
    # `execute(..., batch_memory=)` (``run --batch-memory``): every task's batches fit it
    from distributed import Client, LocalCluster

    from service.batching import sample_memory

    sweep_file(tmp_path, realisations=3)
    plan = parse_sweep((tmp_path / "sweep.yaml").read_text(), folder=tmp_path)
    per_sample = max(sample_memory(scene) for scene in plan.scenes)
    sizes = []
    real = service.tasks.render_samples

    def spy(scene, seeds, *, backend):
        sizes.append(len(seeds))
        return real(scene, seeds, backend=backend)

    monkeypatch.setattr(service.tasks, "render_samples", spy)
    options = {"processes": False, "n_workers": 1, "threads_per_worker": 1}
    with (
        LocalCluster(dashboard_address=None, **options) as cluster,
        Client(cluster, set_as_default=False) as client,
    ):
        for memory, output in ((1.5 * per_sample, "one.zarr"), (None, "all.zarr")):
            sizes.clear()
            store = Store.at(str(tmp_path / output))
            common = {"client": client, "batch_size": 6}
            assert execute(plan, store, batch_memory=memory, **common).ok
            assert sorted(sizes) == ([1] * 6 if memory else [3, 3])
    assert_same_samples(str(tmp_path / "one.zarr"), str(tmp_path / "all.zarr"), names=None)


def test_a_batch_takes_half_the_memory_a_task_has_on_its_device(monkeypatch):
    # issue #39 item 5: on a dask worker its memory limit shared by its threads; elsewhere
    # this machine's memory (dask's MEMORY_LIMIT, what the embedded cluster shares) by the
    # workers; on a GPU its memory shared by the GPU_TASKS tasks its worker runs at once
    from distributed import Client, LocalCluster
    from distributed.system import MEMORY_LIMIT

    from service.batching import BUDGET_SHARE, batch_samples, memory_budget, task_memory

    assert BUDGET_SHARE == 0.5
    assert task_memory(NUMPY, workers=4)[0] == MEMORY_LIMIT / 4
    assert memory_budget(NUMPY, workers=4) == MEMORY_LIMIT / 8
    assert memory_budget(NUMPY, 3e9, workers=4) == 3e9  # --batch-memory
    options = {"processes": False, "n_workers": 1, "threads_per_worker": 2}
    with (
        LocalCluster(memory_limit=2**30, dashboard_address=None, **options) as cluster,
        Client(cluster, set_as_default=False) as client,
    ):
        # `workers` counts this machine's workers off a worker: a worker knows its own limit
        memory, source = client.submit(lambda: task_memory(NUMPY, workers=16)).result()
    assert memory == 2**30 / 2 and "2 thread(s)" in source

    class Properties:
        total_memory = 80 * 2**30

    torch = pytest.importorskip("torch")
    monkeypatch.setattr(torch.cuda, "get_device_properties", lambda device: Properties)
    cuda = Backend(name="torch", device="cuda")
    assert task_memory(cuda) == (
        80 * 2**30 / GPU_TASKS,
        f"cuda's memory shared by {GPU_TASKS} tasks",
    )
    scene = parse_sweep(TINY_SWEEP.format(name="t", seed=1, realisations=1, output="o")).scenes[0]
    from service.batching import sample_memory

    assert batch_samples(scene, 7.9 * sample_memory(scene)) == 7
    assert batch_samples(scene, 1.0) == 1


@pytest.fixture
def gpu_and_cpu_workers():
    """A cluster in this process: a worker advertising `GPU_TASKS` GPU slots, one without."""
    from distributed import Client, Scheduler, SpecCluster, Worker

    workers = {
        "gpu": {
            "cls": Worker,
            "options": {"nthreads": GPU_TASKS, "resources": {"GPU": GPU_TASKS}},
        },
        "cpu": {"cls": Worker, "options": {"nthreads": 1}},
    }
    scheduler = {
        "cls": Scheduler,
        "options": {"dashboard_address": "127.0.0.1:0", "host": "127.0.0.1"},
    }
    with (
        SpecCluster(workers=workers, scheduler=scheduler) as cluster,
        Client(cluster, set_as_default=False) as client,
    ):
        yield client


def test_a_cuda_run_on_a_scheduler_renders_on_its_gpu_workers_only(
    tmp_path, gpu_and_cpu_workers, monkeypatch, numpy_store
):
    # issue #28 item 5: with --scheduler, tasks carry resources={"GPU": 1}: a worker without
    # a GPU renders nothing; the worker checks the backend (before anything is written);
    # the store records torch on cuda. (No GPU here: the renders are numpy's, the backend
    # they were asked for is recorded by a spy.)
    from distributed import get_worker

    seen, lock = [], threading.Lock()
    real = service.tasks.render_samples

    def spy(scene, seeds, *, backend):
        with lock:
            seen.append((get_worker().name, backend))
        return real(scene, seeds, backend=NUMPY)

    checked = []
    monkeypatch.setattr(service.tasks, "render_samples", spy)
    monkeypatch.setattr(
        service.run, "check_on_worker", lambda b: checked.append((get_worker().name, b))
    )
    # nor a GPU's memory to size the batches by (`service.batching.task_memory`)
    monkeypatch.setattr(service.tasks, "memory_budget", lambda backend, memory: 2**30)
    sweep_file(tmp_path)
    plan = parse_sweep((tmp_path / "sweep.yaml").read_text(), folder=tmp_path)
    store = Store.at(str(tmp_path / "out.zarr"))
    cuda = choose(None, "cuda", here=False)
    result = execute(plan, store, client=gpu_and_cpu_workers, batch_size=2, backend=cuda)
    assert result.ok and result.written == plan.samples
    assert checked == [("gpu", cuda)]
    assert seen and {name for name, _ in seen} == {"gpu"}
    assert {backend for _, backend in seen} == {cuda}
    with xr.open_zarr(store.url) as ds:
        assert (ds.attrs["render_backend"], ds.attrs["render_device"]) == ("torch", "cuda")
    assert_same_samples(numpy_store / "out.zarr", store.url)


@pytest.mark.skipif(cuda_here(), reason="this machine has a CUDA device")
def test_a_gpu_worker_that_cannot_render_on_cuda_refuses_the_run_before_writing(
    tmp_path, gpu_and_cpu_workers
):
    # issue #28 item 5: a scheduler's GPU worker checks the backend with get_backend (here
    # it has no CUDA device): exit 2's kind, the flag named, nothing written
    sweep_file(tmp_path)
    plan = parse_sweep((tmp_path / "sweep.yaml").read_text(), folder=tmp_path)
    store = Store.at(str(tmp_path / "out.zarr"))
    message = (
        "--device: 'cuda' asked, but this machine has no CUDA device (on the cluster's worker)"
    )
    with pytest.raises(BadOptionError) as refused:
        execute(plan, store, client=gpu_and_cpu_workers, backend=choose(None, "cuda", here=False))
    assert str(refused.value) == message
    assert sorted(p.name for p in tmp_path.iterdir()) == ["sweep.yaml"]


class FakeCUDAClusterError(Exception):
    """Raised by the fake dask_cuda.LocalCUDACluster with its arguments."""


@pytest.fixture
def fake_dask_cuda(monkeypatch):
    module = types.ModuleType("dask_cuda")
    module.__spec__ = importlib.machinery.ModuleSpec("dask_cuda", None)

    def local_cuda_cluster(**options):
        raise FakeCUDAClusterError(options)

    module.LocalCUDACluster = local_cuda_cluster
    monkeypatch.setitem(sys.modules, "dask_cuda", module)
    return module


@pytest.mark.parametrize(("device", "visible"), [("cuda", None), ("cuda:1", "1")])
def test_cuda_without_a_scheduler_starts_dask_cudas_cluster_on_loopback(
    fake_dask_cuda, device, visible
):
    # issue #28 item 5: LocalCUDACluster, one worker a GPU, two shard tasks each (GPU
    # resource), on 127.0.0.1 only; dask-cuda imported only then
    with (
        pytest.raises(FakeCUDAClusterError) as started,
        dask_client(workers=None, scheduler=None, device=device),
    ):
        pass
    (options,) = started.value.args
    assert options["CUDA_VISIBLE_DEVICES"] == visible
    assert options["threads_per_worker"] == GPU_TASKS == 2
    assert options["resources"] == {"GPU": GPU_TASKS}
    assert options["host"] == "127.0.0.1"
    assert options["dashboard_address"].startswith("127.0.0.1:")


def test_cuda_without_dask_cuda_is_a_clear_error(monkeypatch):
    real = importlib.util.find_spec
    monkeypatch.setattr(
        importlib.util,
        "find_spec",
        lambda name, *a: None if name == "dask_cuda" else real(name, *a),
    )
    with (
        pytest.raises(BadOptionError) as refused,
        dask_client(workers=None, scheduler=None, device="cuda"),
    ):
        pass
    assert str(refused.value) == (
        "--device cuda: the local CUDA cluster needs dask-cuda, which is not installed (pip "
        "install 'oceanlidar[gpu]' for dask-cuda, or give --scheduler a cluster of GPU workers)"
    )


def test_validate_times_the_render_on_the_chosen_backend(work, cli, monkeypatch):
    # issue #28 item 5: `validate --backend torch` times a batch on torch (a task's batch)
    import service.cli.run_commands as commands

    timed = []
    real = commands.render_samples

    def spy(scene, seeds, *, backend):
        timed.append((len(seeds), backend))
        return real(scene, seeds, backend=NUMPY)

    monkeypatch.setattr(commands, "render_samples", spy)
    result = cli("validate", "sweep.yaml", "--backend", "torch", cwd=work)
    assert result.returncode == 0, result.stderr
    assert timed == [(2, TORCH_CPU)] * 3  # compiled, set up, caches cleared; 2 realisations
    assert "run time: about" in result.stdout
    timed.clear()
    assert cli("validate", "sweep.yaml", cwd=work).returncode == 0
    assert timed == [(1, NUMPY)] * 3


def test_the_gpu_extra_installs_what_device_cuda_needs():
    # issue #28 item 6: pip install 'oceanlidar[gpu]' adds torch and dask-cuda; [train] torch
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    names = {
        extra: {re.split("[<>=;\\[ ]", requirement)[0] for requirement in requirements}
        for extra, requirements in project["optional-dependencies"].items()
    }
    assert {"torch", "dask-cuda"} <= names["gpu"]
    assert "torch" in names["train"]
    assert "torch" in names["test"]


@pytest.mark.skipif(not cuda_here(), reason="needs a CUDA device (torch.cuda.is_available())")
@pytest.mark.skipif(
    importlib.util.find_spec("dask_cuda") is None, reason="needs dask-cuda ('oceanlidar[gpu]')"
)
def test_a_cuda_run_gives_the_same_bytes_twice(tmp_path, cli):
    # issue #28 items 3, 5: `run --device cuda` on dask-cuda's cluster; same seed, same bytes
    sweep_file(tmp_path)
    for output in ("a.zarr", "b.zarr"):
        result = cli("run", "sweep.yaml", "--device", "cuda", "--output", output, cwd=tmp_path)
        assert result.returncode == 0, result.stderr
    with xr.open_zarr(tmp_path / "a.zarr") as ds:
        assert (ds.attrs["render_backend"], ds.attrs["render_device"]) == ("torch", "cuda")
        assert np.isfinite(ds.image.values).all()
    assert_same_samples(tmp_path / "a.zarr", tmp_path / "b.zarr")


def test_a_torch_run_records_torch_and_gives_the_same_bytes_twice(tmp_path, cli, shared_cluster):
    # issue #28 items 3, 5: `run --backend torch` (the CPU here) through the whole service:
    # the store says torch, and the same seed gives the same bytes again
    sweep_file(tmp_path)
    for output in ("a.zarr", "b.zarr"):
        result = cli("run", "sweep.yaml", "--backend", "torch", "--output", output, cwd=tmp_path)
        assert result.returncode == 0, result.stderr
    with xr.open_zarr(tmp_path / "a.zarr") as ds:
        assert (ds.attrs["render_backend"], ds.attrs["render_device"]) == ("torch", "cpu")
        assert ds.completed.values.all()
    assert_same_samples(tmp_path / "a.zarr", tmp_path / "b.zarr")


def test_detect_renders_again_on_the_backend_that_wrote_the_store():
    # found by a trial: detect re-rendered a torch store's samples on numpy, whose noise
    # differs, and blamed "another oceanlidar version"
    import xarray as xr

    from service.devices import written_by
    from service.errors import BadSweepError

    written = xr.Dataset(attrs={"render_backend": "torch", "render_device": "cpu"}).attrs
    assert written_by(written, "s.zarr") == TORCH_CPU
    assert written_by(xr.Dataset().attrs, "old.zarr") == NUMPY  # stores before 0.3
    if not cuda_here():
        written["render_device"] = "cuda"
        with pytest.raises(BadSweepError, match="rendered with --backend torch --device cuda"):
            written_by(written, "s.zarr")
