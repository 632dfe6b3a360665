"""Run an oceanlidar sweep on a SLURM cluster with dask-jobqueue, over TLS.

Run it on a login node, in the environment the project is installed in, on a filesystem the
compute nodes share (the workers start this same interpreter, so dask versions match)::

    pip install . dask-jobqueue cryptography    # and s3fs for s3:// stores
    python deploy/slurm/run_sweep.py configs/mldc-detection.yaml --jobs 4 --cores 16 \
        --memory 64GB --walltime 02:00:00 --queue compute --account myproject --resume

The scheduler runs in this process; each SLURM job starts --cores single-threaded worker
processes. Arguments this script does not know (--resume, --overwrite, --batch,
--storage-options) go to ``oceanlidar run``. --dry-run prints the job script and exits.

On GPUs (``pip install '.[gpu]'``), ``--gpus`` makes each job one GPU (``--gres=gpu:1``;
SLURM sets its ``CUDA_VISIBLE_DEVICES``) and one worker of two threads that advertises two
units of the ``GPU`` resource (``service.cluster.GPU_TASKS``: one shard renders while the
other is written), and runs ``oceanlidar run --device cuda``, whose tasks each ask for one::

    python deploy/slurm/run_sweep.py configs/quickstart.yaml --gpus --jobs 4 \
        --memory 32GB --queue gpu --account myproject --resume

TLS: ``Security.temporary()`` makes a key and a self-signed certificate in memory;
dask-jobqueue writes the workers' copy (files of mode 600) into --shared-dir, which the
compute nodes must see, and deletes them when the cluster closes. Encryption is required, so
nothing connects in plain TCP; scheduler and workers keep their HTTP servers on loopback.
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import dask
from dask_jobqueue import SLURMCluster
from distributed.security import Security

from service.cli import main as oceanlidar
from service.cluster import GPU_TASKS
from service.tuning import ALLOCATOR_ENVIRONMENT


def make_cluster(args: argparse.Namespace, security: Security) -> SLURMCluster:
    """A SLURMCluster whose scheduler, workers and jobs all use `security`."""
    shared = os.path.expanduser(args.shared_dir)
    os.makedirs(shared, mode=0o700, exist_ok=True)
    worker = ["--no-dashboard", "--dashboard-address", "127.0.0.1:0"]
    if args.gpus:  # one GPU a job: one worker, GPU_TASKS threads and as many GPU slots
        cores, gpu = GPU_TASKS, ["--gres=gpu:1"]
        worker += ["--resources", f"GPU={GPU_TASKS}"]
    else:
        cores, gpu = args.cores, []
    return SLURMCluster(
        cores=cores,
        processes=1 if args.gpus else cores,  # else one thread a process, as embedded
        memory=args.memory,
        walltime=args.walltime,
        queue=args.queue,
        account=args.account,
        interface=args.interface,
        security=security,  # protocol becomes tls://
        shared_temp_directory=shared,
        scheduler_options={"dashboard": False, "dashboard_address": "127.0.0.1:8787"},
        worker_extra_args=worker,
        job_extra_directives=gpu,
        # glibc allocator thresholds for the render processes (service/tuning.py)
        job_script_prologue=[f"export {k}={v}" for k, v in ALLOCATOR_ENVIRONMENT.items()],
    )


def main(argv: list[str] | None = None) -> int:
    """Start the cluster, wait for its workers, run the sweep; return its exit code."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("sweep", help="sweep YAML file")
    parser.add_argument("--output", help="store path or URL (default: the sweep's output)")
    parser.add_argument("--jobs", type=int, default=2, help="SLURM jobs (default 2)")
    parser.add_argument("--cores", type=int, default=8, help="cores = workers per job")
    parser.add_argument("--memory", default="32GB", help="memory per job (default 32GB)")
    parser.add_argument("--walltime", default="01:00:00", help="per job (default 1 h)")
    parser.add_argument("--queue", help="SLURM partition")
    parser.add_argument("--account", help="SLURM account")
    parser.add_argument("--interface", help="network interface of the workers, e.g. ib0")
    parser.add_argument("--shared-dir", default="~/.oceanlidar-dask", help="seen by all nodes")
    parser.add_argument("--wait", type=float, default=3600.0, help="seconds to wait for jobs")
    parser.add_argument("--gpus", action="store_true", help="one GPU a job: --device cuda")
    parser.add_argument("--dry-run", action="store_true", help="print the job script, exit")
    args, run_args = parser.parse_known_args(argv)

    security = Security.temporary()
    # `oceanlidar run --scheduler` builds its client's Security from dask's configuration:
    # give it the client half of the same credentials, and refuse plain TCP everywhere.
    tls = {
        "distributed.comm.require-encryption": True,
        "distributed.comm.tls.ca-file": security.tls_ca_file,
        "distributed.comm.tls.client.cert": security.tls_client_cert,
        "distributed.comm.tls.client.key": security.tls_client_key,
    }
    with dask.config.set(tls), make_cluster(args, security) as cluster:
        if args.dry_run:
            print(cluster.job_script())
            return 0
        cluster.scale(jobs=args.jobs)
        wanted = args.jobs * (1 if args.gpus else args.cores)
        deadline = time.monotonic() + args.wait
        # the run sizes its in-flight window from the workers present at its start
        while (count := len(cluster.scheduler_info["workers"])) < wanted:
            if time.monotonic() > deadline:
                break
            time.sleep(5.0)
        if count == 0:
            print(f"no worker started in {args.wait:g} s (squeue?)", file=sys.stderr)
            return 1
        output = ["--output", args.output] if args.output else []
        command = ["run", args.sweep, "--scheduler", cluster.scheduler_address]
        command += ["--device", "cuda"] if args.gpus else []
        return oceanlidar([*command, *output, *run_args])


if __name__ == "__main__":
    sys.exit(main())
