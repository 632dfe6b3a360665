"""The deploy/ recipes for GPU workers (issue #28 item 5): Kubernetes and SLURM."""

import importlib.machinery
import importlib.util
import sys
import types
from typing import ClassVar

import pytest
import yaml
from conftest import ROOT

from service.cli.parser import parser
from service.cluster import GPU_TASKS
from service.run import GPU_RESOURCE

KUBERNETES = ROOT / "deploy" / "kubernetes"


def manifest(name):
    (document,) = yaml.safe_load_all((KUBERNETES / name).read_text())
    return document


def container(pod_spec):
    (only,) = pod_spec["containers"]
    return only


def test_the_gpu_worker_group_joins_the_cluster_with_one_gpu_and_two_task_slots_a_pod():
    cluster, group = manifest("daskcluster.yaml"), manifest("gpu-workers.yaml")
    assert group["apiVersion"] == cluster["apiVersion"] == "kubernetes.dask.org/v1"
    assert group["kind"] == "DaskWorkerGroup"
    assert group["spec"]["cluster"] == cluster["metadata"]["name"]
    gpu, cpu = (
        container(group["spec"]["worker"]["spec"]),
        container(cluster["spec"]["worker"]["spec"]),
    )
    assert gpu["command"][:4] == ["dask", "cuda", "worker", "$(DASK_SCHEDULER_ADDRESS)"]
    # as many threads as GPU slots, each task taking one: GPU_TASKS shards at once
    assert f"--nthreads={GPU_TASKS}" in gpu["command"]
    assert f"--resources=GPU={GPU_TASKS}" in gpu["command"]
    assert GPU_RESOURCE == {"GPU": 1}
    assert gpu["resources"]["limits"]["nvidia.com/gpu"] == 1
    # the same TLS-only settings, certificates and store credentials as the CPU workers
    assert gpu["env"] == cpu["env"]
    assert gpu["envFrom"] == cpu["envFrom"]
    assert (
        group["spec"]["worker"]["spec"]["volumes"] == cluster["spec"]["worker"]["spec"]["volumes"]
    )
    assert {"--no-dashboard", "--dashboard-address=127.0.0.1:0"} <= set(gpu["command"])


def test_the_gpu_runner_runs_the_sweep_with_device_cuda_on_that_cluster():
    cpu = container(manifest("runner-job.yaml")["spec"]["template"]["spec"])
    gpu = container(manifest("runner-job-gpu.yaml")["spec"]["template"]["spec"])
    assert gpu["env"] == cpu["env"]
    command = gpu["command"]
    run = command[command.index("--") + 1 :]
    assert run[0] == "oceanlidar"
    args = parser().parse_args(run[1:])
    assert (args.command, args.device, args.backend) == ("run", "cuda", None)
    assert args.scheduler == "$(DASK_SCHEDULER_ADDRESS)" and args.resume
    assert (
        gpu["image"] == container(manifest("gpu-workers.yaml")["spec"]["worker"]["spec"])["image"]
    )


class FakeSLURMCluster:
    """dask_jobqueue.SLURMCluster as the recipe uses it: its options kept, no jobs."""

    made: ClassVar[list] = []

    def __init__(self, **options):
        self.options = options
        self.scheduler_address = "tls://10.0.0.1:8786"
        self.scheduler_info = {"workers": {"w": {}}}
        FakeSLURMCluster.made.append(self)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False

    def scale(self, jobs):
        self.jobs = jobs


@pytest.fixture
def run_sweep(monkeypatch):
    """deploy/slurm/run_sweep.py, imported with a stand-in for dask-jobqueue."""
    fake = types.ModuleType("dask_jobqueue")
    fake.__spec__ = importlib.machinery.ModuleSpec("dask_jobqueue", None)
    fake.SLURMCluster = FakeSLURMCluster
    monkeypatch.setitem(sys.modules, "dask_jobqueue", fake)
    FakeSLURMCluster.made = []
    spec = importlib.util.spec_from_file_location("run_sweep", ROOT / "deploy/slurm/run_sweep.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.mark.parametrize("gpus", [True, False], ids=["gpus", "cpus"])
def test_the_slurm_recipe_asks_one_gpu_a_job_and_runs_on_cuda(run_sweep, tmp_path, gpus):
    ran = []
    run_sweep.oceanlidar = lambda argv: ran.append(argv) or 0
    flags = ["--gpus"] if gpus else []
    argv = [
        "sweep.yaml",
        "--jobs",
        "3",
        "--cores",
        "8",
        "--shared-dir",
        str(tmp_path),
        "--wait",
        "0",
    ]
    assert run_sweep.main([*argv, *flags, "--resume"]) == 0
    (cluster,) = FakeSLURMCluster.made
    options = cluster.options
    assert cluster.jobs == 3
    (command,) = ran
    if gpus:
        assert options["job_extra_directives"] == ["--gres=gpu:1"]
        assert (options["cores"], options["processes"]) == (GPU_TASKS, 1)
        extra = options["worker_extra_args"]
        assert extra[extra.index("--resources") + 1] == f"GPU={GPU_TASKS}"
        assert command[command.index("--device") + 1] == "cuda"
    else:
        assert options["job_extra_directives"] == []
        assert (options["cores"], options["processes"]) == (8, 8)
        assert "--resources" not in options["worker_extra_args"]
        assert "--device" not in command
    assert "--resume" in command
    args = parser().parse_args(command)
    assert args.scheduler == "tls://10.0.0.1:8786"
