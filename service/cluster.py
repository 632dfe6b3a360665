"""The dask client a run uses: an existing scheduler, or an embedded LocalCluster on loopback."""

from __future__ import annotations

import contextlib
import logging
import os

from distributed import Client, LocalCluster

__all__ = ["ClusterError", "dask_client"]

CLOSE_TIMEOUT = 60.0
"""Longest wait for the embedded cluster's workers to exit, s."""

_log = logging.getLogger(__name__)


class ClusterError(RuntimeError):
    """The dask cluster cannot be reached or used."""


@contextlib.contextmanager
def dask_client(*, workers: int | None, scheduler: str | None, security=None):
    """A client for an existing scheduler, or for an embedded LocalCluster on 127.0.0.1.

    `security` (a `distributed.Security`) defaults to dask's configuration, where TLS
    files and ``require-encryption`` can be set (``DASK_DISTRIBUTED__COMM__...``).
    """
    if scheduler is not None:
        try:
            client = Client(scheduler, security=security, timeout="30s")
        except (OSError, TimeoutError, ValueError) as error:
            raise ClusterError(
                f"cannot connect to the scheduler at {scheduler}: {error}"
            ) from None
        with client:
            yield client
        return
    cluster = LocalCluster(
        n_workers=workers or os.cpu_count() or 1,
        threads_per_worker=1,
        processes=True,
        host="127.0.0.1",
        dashboard_address=None,
        silence_logs=logging.CRITICAL,
    )
    try:
        with Client(cluster) as client:
            yield client
    finally:
        # A worker slow to exit (a loaded machine) must not turn a finished run into a
        # traceback: what it wrote is complete, and its process is killed at exit anyway.
        try:
            cluster.close(timeout=CLOSE_TIMEOUT)
        except TimeoutError:
            _log.warning("the embedded dask cluster did not shut down within %g s", CLOSE_TIMEOUT)
