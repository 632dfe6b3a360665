"""The batch service's job table (SQLite) and the runner that works it off on one cluster.

A job is a submitted sweep: its YAML text (never credentials), its owner, its state and its
progress. The table is the service's memory across restarts: a job found ``running`` when
the service starts was interrupted (a crash, a kill) and is run again with resume, so it
completes from its store with the same bytes as an undisturbed run; queued jobs stay
queued.

Several jobs run at once on the one dask client. Each keeps a bounded window of tasks in
flight (`service.run.run_plan`) and the scheduler starts tasks in submission order, so the
jobs running take turns on the workers: none starves another.
"""

from __future__ import annotations

import fcntl
import json
import os
import sqlite3
import threading
import time
import uuid

import fsspec

from service.inputs import MAX_FILE_BYTES, SweepError, shown
from service.run import execute
from service.store.template import check_uniform
from service.sweep import DEFAULT_MAX_MEMORY, parse_sweep

__all__ = [
    "ACTIVE",
    "FINAL",
    "ForbiddenError",
    "JobTable",
    "QueueFullError",
    "Runner",
    "confine_output",
]

ACTIVE = ("queued", "running")
FINAL = ("succeeded", "failed", "cancelled")
MODES = ("new", "resume", "overwrite")
DISPATCH_TICK = 0.2
"""Seconds between looks for queued jobs to start."""

_SCHEMA = """
CREATE TABLE IF NOT EXISTS jobs (
    id TEXT PRIMARY KEY, owner TEXT NOT NULL, name TEXT NOT NULL, state TEXT NOT NULL,
    mode TEXT NOT NULL, sweep TEXT NOT NULL, output TEXT NOT NULL, url TEXT NOT NULL,
    submitted REAL NOT NULL, started REAL, finished REAL, total INTEGER NOT NULL,
    done INTEGER NOT NULL DEFAULT 0, rate REAL NOT NULL DEFAULT 0, message TEXT,
    errors TEXT NOT NULL DEFAULT '{}', interrupted INTEGER NOT NULL DEFAULT 0
)
"""


class QueueFullError(RuntimeError):
    """The service holds as many unfinished jobs as its queue limit allows."""


class ForbiddenError(RuntimeError):
    """A submitter acts on another owner's job or store."""


class JobTable:
    """Jobs in an SQLite file, safe to use from several threads, owned by one service.

    The service holds an exclusive lock on ``PATH.lock`` (``flock``) while the table is
    open, released by the system when its process ends however it ends: a job found
    ``running`` at start was left by a service that has died, whose store locks (they
    name the job) may then be taken over (`service.store.lock.writer_lock`).

    Parameters
    ----------
    path : str
        The database file (created if absent).

    Raises
    ------
    SweepError
        If another service has the table open.
    """

    def __init__(self, path: str):
        self._owner = open(f"{path}.lock", "a")  # held while the table lives
        try:
            fcntl.flock(self._owner, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            self._owner.close()
            raise SweepError(
                f"--db {path}: another oceanlidar serve uses this job table (one service a table)"
            ) from None
        self._db = sqlite3.connect(path, check_same_thread=False, isolation_level=None)
        self._db.row_factory = sqlite3.Row
        self._lock = threading.Lock()
        self._query("PRAGMA journal_mode=WAL")
        self._query(_SCHEMA)

    def _query(self, sql: str, parameters=()) -> list[dict]:
        with self._lock:
            return [dict(row) for row in self._db.execute(sql, parameters)]

    def add(self, **fields) -> None:
        """Insert one job (every column without a default given by name)."""
        names = ", ".join(fields)
        marks = ", ".join("?" for _ in fields)
        self._query(f"INSERT INTO jobs ({names}) VALUES ({marks})", tuple(fields.values()))

    def get(self, job_id: str) -> dict | None:
        """The job `job_id`, or None."""
        rows = self._query("SELECT * FROM jobs WHERE id = ?", (job_id,))
        return rows[0] if rows else None

    def list(self, state: str | None = None) -> list[dict]:
        """Jobs, newest first, of one state if `state` is given."""
        if state is None:
            return self._query("SELECT * FROM jobs ORDER BY submitted DESC, rowid DESC")
        return self._query(
            "SELECT * FROM jobs WHERE state = ? ORDER BY submitted DESC, rowid DESC", (state,)
        )

    def latest(self, url: str) -> dict | None:
        """The newest job that writes (or wrote) the store `url`, or None."""
        rows = self._query(
            "SELECT * FROM jobs WHERE url = ? ORDER BY submitted DESC, rowid DESC LIMIT 1", (url,)
        )
        return rows[0] if rows else None

    def update(self, job_id: str, **fields) -> None:
        """Set columns of one job."""
        names = ", ".join(f"{name} = ?" for name in fields)
        self._query(f"UPDATE jobs SET {names} WHERE id = ?", (*fields.values(), job_id))

    def set_state(self, job_id: str, state: str, *, when: tuple = ACTIVE, **fields) -> bool:
        """Move a job to `state` if it is in one of `when`; whether it moved."""
        names = "".join(f", {name} = ?" for name in fields)
        marks = ", ".join("?" for _ in when)
        with self._lock:
            cursor = self._db.execute(
                f"UPDATE jobs SET state = ?{names} WHERE id = ? AND state IN ({marks})",
                (state, *fields.values(), job_id, *when),
            )
            return cursor.rowcount == 1

    def active(self) -> int:
        """How many jobs are queued or running."""
        return self._query("SELECT COUNT(*) AS n FROM jobs WHERE state IN ('queued', 'running')")[
            0
        ]["n"]

    def next_queued(self) -> dict | None:
        """The job to start next: interrupted ones first, then the oldest."""
        rows = self._query(
            "SELECT * FROM jobs WHERE state = 'queued' "
            "ORDER BY interrupted DESC, submitted, rowid LIMIT 1"
        )
        return rows[0] if rows else None

    def recover(self) -> int:
        """Queue again, to resume, the jobs a previous service left running; how many."""
        with self._lock:
            return self._db.execute(
                "UPDATE jobs SET state = 'queued', interrupted = 1 WHERE state = 'running'"
            ).rowcount


def confine_output(output: str, data_root: str) -> str:
    """The store URL of a sweep's `output` under `data_root`.

    Raises
    ------
    SweepError
        If `output` is a URL (chained ``::`` ones included) or an absolute path, or climbs
        out of `data_root`, as written or through links.
    """
    if any(ord(character) < 32 for character in output):
        raise SweepError(f"output: control characters are not allowed, got {shown(output)}")
    protocol, _ = fsspec.core.split_protocol(output)
    normal = os.path.normpath(output)
    if (
        protocol is not None
        or "://" in output
        or "::" in output
        or os.path.isabs(output)
        or normal == os.curdir
        or normal.split(os.sep)[0] == os.pardir
    ):
        raise SweepError(
            f"output: must be a path relative to the service's data root, inside it, "
            f"got {shown(output)}"
        )
    url = f"{data_root.rstrip('/')}/{normal}"
    if fsspec.core.split_protocol(data_root)[0] in (None, "file", "local"):
        root = os.path.realpath(data_root)
        if os.path.commonpath([root, os.path.realpath(url)]) != root:
            raise SweepError(f"output: {shown(output)} leads out of the service's data root")
    return url


def _parents(url: str) -> list[str]:
    """The folders `url` lies in, innermost first (``a/b/c`` → ``a/b``, ``a``)."""
    parts = url.rstrip("/").split("/")
    return ["/".join(parts[:depth]) for depth in range(len(parts) - 1, 0, -1)]


def public(job: dict) -> dict:
    """A job as the API shows it."""
    left = (job["total"] - job["done"]) / job["rate"] if job["rate"] > 0 else None
    fields = ("id", "name", "owner", "state", "mode", "output", "submitted", "started")
    return {
        **{name: job[name] for name in fields},
        "finished": job["finished"],
        "url": job["url"],
        "samples": {"done": job["done"], "total": job["total"]},
        "rate": job["rate"],
        "seconds_left": left if job["state"] == "running" else None,
        "message": job["message"],
        "resumed": bool(job["interrupted"]),
        "errors": json.loads(job["errors"]),
    }


class Runner:
    """Admits sweeps into the job table and runs them on a dask client.

    Parameters
    ----------
    table : JobTable
        The jobs.
    client : distributed.Client
        The one cluster every job runs on.
    data_root : Store
        Folder or object-storage prefix that every output lies under and every
        measurement file is read from, with the fsspec options of the service (never a
        submitter's).
    max_running : int
        Jobs run at once; the others wait, in order.
    queue_limit : int
        Most unfinished (queued or running) jobs; more are refused (`QueueFullError`).
    batch_size : int or None
        Samples per shard and task of a new store; None: `service.store.layout.shard_size`'s.
    """

    def __init__(self, table, client, *, data_root, max_running, queue_limit, batch_size):
        self.table, self.client, self.data_root = table, client, data_root
        self.max_running, self.queue_limit, self.batch_size = max_running, queue_limit, batch_size
        self._running: dict[str, tuple[threading.Thread, threading.Event]] = {}
        self._stop = threading.Event()
        self._admit = threading.Lock()
        self._dispatcher = threading.Thread(target=self._dispatch, name="jobs", daemon=True)

    def start(self) -> None:
        """Requeue interrupted jobs and start working the queue."""
        self.table.recover()
        self._dispatcher.start()

    def stop(self) -> None:
        """Stop running jobs resumably (they stay ``running`` and resume at the next start)."""
        self._stop.set()
        for _, cancel in list(self._running.values()):
            cancel.set()
        for thread, _ in list(self._running.values()):
            thread.join(timeout=30)
        self._dispatcher.join(timeout=5)

    def plan(self, text: str, mode: str):
        """Check a submitted sweep as ``oceanlidar run`` would; its plan and store URL.

        Raises
        ------
        SweepError
            With the field path and the reason; nothing is queued or written.
        """
        if mode not in MODES:
            raise SweepError(f"mode: must be one of {', '.join(MODES)}, got {shown(mode)}")
        if len(text.encode()) > MAX_FILE_BYTES:
            raise SweepError(f"the sweep is larger than {MAX_FILE_BYTES:,} bytes")
        plan = parse_sweep(text, folder=self.data_root.url, max_memory=DEFAULT_MAX_MEMORY)
        plan.check_limits(remedy="split it into smaller sweeps (the service's limit)")
        check_uniform(plan)
        url = confine_output(plan.sweep.output, self.data_root.url)
        root = self.data_root.url.rstrip("/")
        for group in _parents(url):
            if not group.startswith(f"{root}/"):
                break
            if self.data_root.other(group).attributes() is not None:
                inside = group[len(root) + 1 :]
                raise SweepError(
                    f"output: {shown(plan.sweep.output)} lies inside the store {shown(inside)}"
                )
        if mode == "new" and self.data_root.other(url).occupied():
            raise SweepError(
                f"output: {shown(plan.sweep.output)} already exists; submit with mode "
                "resume (oceanlidar submit --resume) to complete it or overwrite "
                "(--overwrite) to replace it"
            )
        return plan, url

    def submit(self, text: str, *, owner: str, mode: str = "new") -> dict:
        """Queue a sweep; the job.

        Raises
        ------
        SweepError
            For a bad sweep, or an output another unfinished job writes.
        ForbiddenError
            If a resume or an overwrite names a store another owner's job wrote.
        QueueFullError
            If `queue_limit` jobs are unfinished.
        """
        plan, url = self.plan(text, mode)
        with self._admit:
            previous = self.table.latest(url)
            if mode != "new" and previous is not None and previous["owner"] != owner:
                raise ForbiddenError(
                    f"output: {shown(plan.sweep.output)} was written by job {previous['id']} "
                    f"of {previous['owner']}; only its owner may {mode} it"
                )
            if self.table.active() >= self.queue_limit:
                raise QueueFullError(f"{self.queue_limit} jobs are queued or running; try later")
            for job in self.table.list("queued") + self.table.list("running"):
                if url in (job["url"], *_parents(job["url"])) or job["url"] in _parents(url):
                    raise SweepError(
                        f"output: job {job['id']} writes {shown(job['url'])}, the same store "
                        "or one inside the other"
                    )
            job_id = uuid.uuid4().hex[:12]
            self.table.add(
                id=job_id,
                owner=owner,
                name=plan.sweep.name,
                state="queued",
                mode=mode,
                sweep=text,
                output=plan.sweep.output,
                url=url,
                submitted=time.time(),
                total=plan.samples,
            )
        return self.table.get(job_id)

    def cancel(self, job_id: str) -> bool:
        """Cancel a queued or running job; False if it had finished."""
        if self.table.set_state(job_id, "cancelled", when=("queued",), finished=time.time()):
            return True
        entry = self._running.get(job_id)
        if entry is None:
            return False
        entry[1].set()
        return True

    def _dispatch(self) -> None:
        while not self._stop.wait(DISPATCH_TICK):
            for job_id, (thread, _) in list(self._running.items()):
                if not thread.is_alive():
                    del self._running[job_id]
            if len(self._running) >= self.max_running:
                continue
            job = self.table.next_queued()
            if job is None or not self.table.set_state(
                job["id"], "running", when=("queued",), started=time.time()
            ):
                continue
            cancel = threading.Event()
            thread = threading.Thread(
                target=self._run, args=(job, cancel), name=f"job-{job['id']}", daemon=True
            )
            self._running[job["id"]] = (thread, cancel)
            thread.start()

    def _run(self, job: dict, cancel: threading.Event) -> None:
        job_id = job["id"]

        def progress(done: int, rate: float) -> None:
            self.table.update(job_id, done=done, rate=rate)

        try:
            plan = parse_sweep(job["sweep"], folder=self.data_root.url, max_memory=None)
            store = self.data_root.other(job["url"])
            # an interrupted job resumes its own store (this sweep's, by its hash); one that
            # was stopped before it made it (an overwrite that had not yet deleted the old
            # store) starts as it was asked
            attributes = store.attributes() or {}
            resume = job["mode"] == "resume" or (
                bool(job["interrupted"]) and attributes.get("sweep_sha256") == plan.digest
            )
            with open(os.devnull, "w") as quiet:
                result = execute(
                    plan,
                    store,
                    client=self.client,
                    resume=resume,
                    overwrite=job["mode"] == "overwrite" and not resume,
                    batch_size=self.batch_size,
                    progress_stream=quiet,
                    cancel=cancel,
                    on_progress=progress,
                    claim=f"oceanlidar service job {job_id}",
                )
        except Exception as error:  # a job's failure must not take the service down
            message = str(error) if isinstance(error, SweepError) else repr(error)
            self.table.set_state(job_id, "failed", finished=time.time(), message=message)
            return
        errors = {str(sample): reason for sample, reason in result.rejected + result.refused}
        for start, count, error in result.failed:
            errors.update({str(s): error for s in range(start, start + count)})
        for start, count in result.stuck:
            errors.update(
                {str(s): "no result before the task timeout" for s in range(start, start + count)}
            )
        fields = {"errors": json.dumps(errors), "finished": time.time()}
        if result.interrupted:
            if self._stop.is_set():  # the service stops: resume at its next start
                self.table.update(job_id, interrupted=1)
                return
            done = int(store.completed().sum())
            message = "cancelled; submit it again with resume to complete it"
            self.table.set_state(job_id, "cancelled", message=message, done=done, **fields)
        elif errors or result.stopped:
            problems = [plan.sample(int(s)).describe() for s in list(errors)[:3]]
            message = result.stopped or "failed: " + "; ".join(problems)
            self.table.set_state(job_id, "failed", message=message, **fields)
        else:
            self.table.set_state(job_id, "succeeded", done=plan.samples, **fields)
