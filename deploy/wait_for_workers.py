"""Wait until a dask scheduler answers and enough workers have joined, then run a command.

    python wait_for_workers.py --scheduler tls://scheduler:8786 --workers 2 -- oceanlidar run ...

`oceanlidar run` sizes its window of tasks in flight from the workers present when it starts
(two per worker thread), so a runner started before its workers would keep only two tasks in
flight for the whole sweep. This waits up to --timeout seconds for --workers workers; with
fewer (but at least one) it warns and goes on; with none it exits 1. TLS settings come from
dask's configuration (the DASK_DISTRIBUTED__COMM__* environment variables), as for the
service's own client. The command after ``--`` replaces this process (``os.execvp``).
"""

from __future__ import annotations

import argparse
import os
import sys
import time

from distributed import Client


def main(argv: list[str] | None = None) -> int:
    """Wait for the cluster, then exec the command (or return its status: 1 if no workers)."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scheduler", required=True, help="scheduler address (tls://...)")
    parser.add_argument("--workers", type=int, default=1, help="workers to wait for")
    parser.add_argument("--timeout", type=float, default=600.0, help="seconds (default 600)")
    parser.add_argument("command", nargs=argparse.REMAINDER, help="-- COMMAND ARGS...")
    args = parser.parse_args(argv)
    command = args.command[1:] if args.command[:1] == ["--"] else args.command
    deadline = time.monotonic() + args.timeout
    try:
        with Client(args.scheduler, timeout=f"{args.timeout}s") as client:
            while (count := len(client.nthreads())) < args.workers:
                if time.monotonic() > deadline:
                    break
                time.sleep(2.0)
    except OSError as error:
        print(f"wait_for_workers: {args.scheduler}: {error}", file=sys.stderr)
        return 1
    if count == 0:
        print(f"wait_for_workers: no worker joined in {args.timeout:g} s", file=sys.stderr)
        return 1
    if count < args.workers:
        print(
            f"wait_for_workers: {count} of {args.workers} workers after {args.timeout:g} s; "
            "going on",
            file=sys.stderr,
        )
    if command:
        sys.stderr.flush()
        os.execvp(command[0], command)
    return 0


if __name__ == "__main__":
    sys.exit(main())
