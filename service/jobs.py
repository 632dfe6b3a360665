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
import os
import sqlite3
import threading
import time
import uuid

from service.admission import admit_job, parents
from service.errors import BadFileError, InputError, LockedError, OutputTakenError
from service.inputs import shown
from service.records import ACTIVE, Job, JobState
from service.run import Cancel, execute
from service.store.template import OWNER
from service.sweep import parse_sweep

__all__ = ["ForbiddenError", "JobTable", "QueueFullError", "Runner"]

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

    The service holds an exclusive lock (``flock``) on the database file itself while the
    table is open: a second service is refused whatever path reaches the file (a symbolic
    or hard link too), and the system releases the lock when the process ends however it
    ends, so a job found ``running`` at start was left by a service that has died, whose
    store locks (they name the job) may then be taken over
    (`service.store.lock.writer_lock`).

    Parameters
    ----------
    path : str
        The database file (created if absent).

    Raises
    ------
    BadFileError
        If `path` cannot be opened (its folder missing, a folder) or is not an SQLite file.
    LockedError
        If another service has the table open.
    """

    def __init__(self, path: str):
        self.path = path
        try:  # held while the table lives
            self._owner = os.open(path, os.O_RDWR | os.O_CREAT, 0o600)
        except OSError as error:  # a missing folder, a folder, no permission
            raise BadFileError(
                f"--db {path}: cannot open the job table ({error.strerror})"
            ) from None
        try:
            fcntl.flock(self._owner, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            os.close(self._owner)
            raise LockedError(
                f"--db {path}: another oceanlidar serve uses this job table (one service a table)"
            ) from None
        self._db = sqlite3.connect(path, check_same_thread=False, isolation_level=None)
        self._db.row_factory = sqlite3.Row
        self._lock = threading.Lock()
        try:
            self._query("PRAGMA journal_mode=WAL")
            self._query(_SCHEMA)
        except sqlite3.DatabaseError as error:  # a file that is not a job table
            self._db.close()
            os.close(self._owner)
            raise BadFileError(f"--db {path}: not an SQLite job table ({error})") from None

    def lost(self) -> str | None:
        """Why the table is no longer the file at its path (deleted, replaced); None if it is.

        A service whose table was lost would forget every job and owner at its next start:
        it must not go on (the server answers ``503``, `service.server`).
        """
        held = os.fstat(self._owner)
        try:
            there = os.stat(self.path)
        except OSError as error:
            return f"the job table --db {self.path} is gone ({error.strerror})"
        if (there.st_dev, there.st_ino) != (held.st_dev, held.st_ino):
            return f"the job table --db {self.path} was replaced by another file"
        return None

    def _query(self, sql: str, parameters=()) -> list[dict]:
        with self._lock:
            return [dict(row) for row in self._db.execute(sql, parameters)]

    def _jobs(self, sql: str, parameters=()) -> list[Job]:
        return [Job.from_row(row) for row in self._query(f"SELECT * FROM jobs {sql}", parameters)]

    def add(self, job: Job) -> None:
        """Insert one job."""
        row = job.row()
        names, marks = ", ".join(row), ", ".join("?" for _ in row)
        self._query(f"INSERT INTO jobs ({names}) VALUES ({marks})", tuple(row.values()))

    def get(self, job_id: str) -> Job | None:
        """The job `job_id`, or None."""
        jobs = self._jobs("WHERE id = ?", (job_id,))
        return jobs[0] if jobs else None

    def list(self, state: str | None = None) -> list[Job]:
        """Jobs, newest first, of one state if `state` is given."""
        if state is None:
            return self._jobs("ORDER BY submitted DESC, rowid DESC")
        return self._jobs("WHERE state = ? ORDER BY submitted DESC, rowid DESC", (state,))

    def latest(self, url: str) -> Job | None:
        """The newest job that writes (or wrote) the store `url`, or None."""
        jobs = self._jobs("WHERE url = ? ORDER BY submitted DESC, rowid DESC LIMIT 1", (url,))
        return jobs[0] if jobs else None

    def update(self, job_id: str, **values) -> None:
        """Set fields of one job (`Job`'s, by name)."""
        columns = Job.columns(**values)
        names = ", ".join(f"{name} = ?" for name in columns)
        self._query(f"UPDATE jobs SET {names} WHERE id = ?", (*columns.values(), job_id))

    def set_state(self, job_id: str, state: JobState, *, when: tuple = ACTIVE, **values) -> bool:
        """Move a job to `state` if it is in one of `when`; whether it moved."""
        columns = Job.columns(**values)
        names = "".join(f", {name} = ?" for name in columns)
        marks = ", ".join("?" for _ in when)
        with self._lock:
            cursor = self._db.execute(
                f"UPDATE jobs SET state = ?{names} WHERE id = ? AND state IN ({marks})",
                (str(state), *columns.values(), job_id, *map(str, when)),
            )
            return cursor.rowcount == 1

    def active(self) -> int:
        """How many jobs are queued or running."""
        marks = ", ".join("?" for _ in ACTIVE)
        rows = self._query(
            f"SELECT COUNT(*) AS n FROM jobs WHERE state IN ({marks})", tuple(map(str, ACTIVE))
        )
        return rows[0]["n"]

    def next_queued(self) -> Job | None:
        """The job to start next: interrupted ones first, then the oldest."""
        jobs = self._jobs(
            "WHERE state = ? ORDER BY interrupted DESC, submitted, rowid LIMIT 1",
            (str(JobState.QUEUED),),
        )
        return jobs[0] if jobs else None

    def recover(self) -> int:
        """Queue again, to resume, the jobs a previous service left running; how many."""
        with self._lock:
            return self._db.execute(
                "UPDATE jobs SET state = ?, interrupted = 1 WHERE state = ?",
                (str(JobState.QUEUED), str(JobState.RUNNING)),
            ).rowcount


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
        self._running: dict[str, tuple[threading.Thread, Cancel]] = {}
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

    def submit(self, text: str, *, owner: str, mode: str = "new") -> Job:
        """Queue a sweep admitted as ``oceanlidar run`` admits it (`admit_job`); the job.

        Raises
        ------
        InputError
            For a bad sweep or mode, or an output this job may not write (another
            unfinished job writes it: `OutputTakenError`).
        ForbiddenError
            If a resume or an overwrite names a store another owner wrote: the store's
            own record (`service.store.template.OWNER`) says who, else the job table's
            newest job into it; a store that records no owner is nobody's to replace.
        QueueFullError
            If `queue_limit` jobs are unfinished.
        """
        plan, url = admit_job(text, mode, data_root=self.data_root)
        with self._admit:
            attributes = self.data_root.other(url).attributes() if mode != "new" else None
            if attributes is not None:  # a store is there
                previous = self.table.latest(url)
                wrote = attributes.get(OWNER, previous.owner if previous else None)
                if wrote != owner:
                    who = f"was written by {wrote}" if wrote else "records no owner"
                    raise ForbiddenError(
                        f"output: {shown(plan.sweep.output)} {who}; only its owner may {mode} it"
                    )
            if self.table.active() >= self.queue_limit:
                raise QueueFullError(f"{self.queue_limit} jobs are queued or running; try later")
            for job in self.table.list(JobState.QUEUED) + self.table.list(JobState.RUNNING):
                if url in (job.url, *parents(job.url)) or job.url in parents(url):
                    raise OutputTakenError(
                        f"output: job {job.id} writes {shown(job.url)}, the same store "
                        "or one inside the other"
                    )
            job = Job(
                id=uuid.uuid4().hex[:12],
                owner=owner,
                name=plan.sweep.name,
                state=JobState.QUEUED,
                mode=mode,
                sweep=text,
                output=plan.sweep.output,
                url=url,
                submitted=time.time(),
                total=plan.samples,
            )
            self.table.add(job)
        return job

    def cancel(self, job_id: str) -> bool:
        """Cancel a queued or running job; False if it had finished or writes its statistics."""
        if self.table.set_state(
            job_id, JobState.CANCELLED, when=(JobState.QUEUED,), finished=time.time()
        ):
            return True
        entry = self._running.get(job_id)
        if entry is None:
            return False
        return entry[1].cancel()

    def _dispatch(self) -> None:
        while not self._stop.wait(DISPATCH_TICK):
            if self.table.lost():  # nothing starts that the next start would not know of
                continue
            for job_id, (thread, _) in list(self._running.items()):
                if not thread.is_alive():
                    del self._running[job_id]
            if len(self._running) >= self.max_running:
                continue
            job = self.table.next_queued()
            if job is None or not self.table.set_state(
                job.id, JobState.RUNNING, when=(JobState.QUEUED,), started=time.time()
            ):
                continue
            cancel = Cancel()
            thread = threading.Thread(
                target=self._run, args=(job, cancel), name=f"job-{job.id}", daemon=True
            )
            self._running[job.id] = (thread, cancel)
            thread.start()

    def _run(self, job: Job, cancel: Cancel) -> None:
        def progress(done: int, rate: float) -> None:
            self.table.update(job.id, done=done, rate=rate)

        try:
            plan = parse_sweep(job.sweep, folder=self.data_root.url, max_memory=None)
            store = self.data_root.other(job.url)
            # an interrupted job resumes its own store (this sweep's, by its hash); one that
            # was stopped before it made it (an overwrite that had not yet deleted the old
            # store) starts as it was asked
            attributes = store.attributes() or {}
            resume = job.mode == "resume" or (
                job.interrupted and attributes.get("sweep_sha256") == plan.digest
            )
            with open(os.devnull, "w") as quiet:
                result = execute(
                    plan,
                    store,
                    client=self.client,
                    resume=resume,
                    overwrite=job.mode == "overwrite" and not resume,
                    batch_size=self.batch_size,
                    progress_stream=quiet,
                    cancel=cancel,
                    on_progress=progress,
                    claim=f"oceanlidar service job {job.id}",
                    owner=job.owner,
                )
        except Exception as error:  # a job's failure must not take the service down
            message = str(error) if isinstance(error, InputError) else repr(error)
            self.table.set_state(job.id, JobState.FAILED, finished=time.time(), message=message)
            return
        errors = {
            str(sample): reason
            for samples in result.problems().values()
            for sample, reason in samples
        }
        finished = {"errors": errors, "finished": time.time()}
        if result.interrupted:
            if self._stop.is_set():  # the service stops: resume at its next start
                self.table.update(job.id, interrupted=True)
                return
            done = int(store.completed().sum())
            message = "cancelled; submit it again with resume to complete it"
            self.table.set_state(
                job.id, JobState.CANCELLED, message=message, done=done, **finished
            )
        elif errors or result.stopped:
            problems = [plan.sample(int(s)).describe() for s in list(errors)[:3]]
            message = result.stopped or "failed: " + "; ".join(problems)
            self.table.set_state(job.id, JobState.FAILED, message=message, **finished)
        else:
            self.table.set_state(job.id, JobState.SUCCEEDED, done=plan.samples, **finished)
