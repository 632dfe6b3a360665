"""The job service's table: its jobs and their logs in one SQLite file (`JobTable`).

The table is the service's memory across restarts (`service.jobs`). An older table (one
made before a column was added) gains the column when it is opened (`_MIGRATIONS`).
"""

from __future__ import annotations

import fcntl
import os
import secrets
import sqlite3
import threading
import time

from service.errors import BadFileError, LockedError
from service.records import ACTIVE, Job, JobState

__all__ = ["JobTable"]

_SCHEMA = (
    """CREATE TABLE IF NOT EXISTS jobs (
    id TEXT PRIMARY KEY, owner TEXT NOT NULL, name TEXT NOT NULL, state TEXT NOT NULL,
    mode TEXT NOT NULL, sweep TEXT NOT NULL, output TEXT NOT NULL, url TEXT NOT NULL,
    submitted REAL NOT NULL, started REAL, finished REAL, total INTEGER NOT NULL,
    done INTEGER NOT NULL DEFAULT 0, rate REAL NOT NULL DEFAULT 0, message TEXT,
    errors TEXT NOT NULL DEFAULT '{}', interrupted INTEGER NOT NULL DEFAULT 0,
    submission_id TEXT, phase TEXT
)""",
    """CREATE TABLE IF NOT EXISTS job_log (
    job TEXT NOT NULL, time REAL NOT NULL, level TEXT NOT NULL, message TEXT NOT NULL
)""",
    "CREATE INDEX IF NOT EXISTS job_log_job ON job_log (job)",
)
_MIGRATIONS = {
    "submission_id": "ALTER TABLE jobs ADD COLUMN submission_id TEXT",
    "phase": "ALTER TABLE jobs ADD COLUMN phase TEXT",
}
"""Columns added since the first job tables, and how an older table gains each."""
IDENTITY = 68
"""Offset [bytes] of the table's identity in its file: SQLite's header field
``application_id``, 4 random bytes drawn when the table is made (an older table gets them
when it is opened). Read from the file itself at every look (`JobTable.lost`), not through
SQLite, which may answer from its cache of the file it opened."""
_LOG = "INSERT INTO job_log (job, time, level, message) VALUES (?, ?, ?, ?)"
_UNIQUE = "CREATE UNIQUE INDEX IF NOT EXISTS jobs_submission ON jobs (owner, submission_id)"


class JobTable:
    """Jobs in an SQLite file, safe to use from several threads, owned by one service.

    The file carries the table's identity (`IDENTITY`): a file copied over it or
    truncated is noticed (`lost`).

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
            for statement in _SCHEMA:
                self._query(statement)
            columns = {row["name"] for row in self._query("PRAGMA table_info(jobs)")}
            for column, statement in _MIGRATIONS.items():
                if column not in columns:
                    self._query(statement)
            self._query(_UNIQUE)
            self._identity = self._identify()
        except sqlite3.DatabaseError as error:  # a file that is not a job table
            self._db.close()
            os.close(self._owner)
            raise BadFileError(f"--db {path}: not an SQLite job table ({error})") from None
        self._lost: str | None = None

    def _identify(self) -> bytes:
        """The table's identity (`IDENTITY`) as its file holds it; drawn for a table without.

        The header is checkpointed out of the write-ahead log into the file first.
        """
        if not self._query("PRAGMA application_id")[0]["application_id"]:
            self._query(f"PRAGMA application_id = {secrets.randbelow(2**31 - 1) + 1}")
        self._query("PRAGMA wal_checkpoint(TRUNCATE)")
        return os.pread(self._owner, 4, IDENTITY)

    def lost(self) -> str | None:
        """Why the table is no longer the file at its path; None if it is.

        Deleted, replaced by another file (``mv``), or overwritten or truncated in place
        (``cp other.sqlite``, ``truncate``: the file's `IDENTITY` differs). A service whose
        table was lost would forget every job and owner at its next start: it must not go
        on (the server answers ``503``, `service.server`); once lost, always lost (a table
        put back is not trusted: restart the service on it).
        """
        if self._lost is None:
            self._lost = self._missing()
        return self._lost

    def _missing(self) -> str | None:
        held = os.fstat(self._owner)
        try:
            there = os.stat(self.path)
        except OSError as error:
            return f"the job table --db {self.path} is gone ({error.strerror})"
        if (there.st_dev, there.st_ino) != (held.st_dev, held.st_ino):
            return f"the job table --db {self.path} was replaced by another file"
        if os.pread(self._owner, 4, IDENTITY) != self._identity:
            return (
                f"the job table --db {self.path} was overwritten or truncated in place (it "
                "no longer holds this service's table)"
            )
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

    def submission(self, owner: str, submission_id: str) -> Job | None:
        """The job `owner` submitted with the id `submission_id`, or None."""
        jobs = self._jobs("WHERE owner = ? AND submission_id = ?", (owner, submission_id))
        return jobs[0] if jobs else None

    def log(self, job_id: str, message: str, *, level: str = "info") -> None:
        """Add a line to the log of job `job_id`; `level` is info, warning or error."""
        self._query(_LOG, (job_id, time.time(), level, message))

    def lines(self, job_id: str) -> list[dict]:
        """The log of job `job_id`, oldest first (a few lines a job: `service.jobs`).

        Each line is a dict: ``seq`` (increasing over the table: a follower prints the
        lines past the last it printed), ``time`` (seconds since the epoch), ``level``
        (info, warning or error), ``message``.
        """
        return self._query(
            "SELECT rowid AS seq, time, level, message FROM job_log WHERE job = ? ORDER BY rowid",
            (job_id,),
        )

    def latest(self, url: str) -> Job | None:
        """The newest job that writes (or wrote) the store `url`, or None."""
        jobs = self._jobs("WHERE url = ? ORDER BY submitted DESC, rowid DESC LIMIT 1", (url,))
        return jobs[0] if jobs else None

    def update(self, job_id: str, **values) -> None:
        """Set fields of one job (`Job`'s, by name)."""
        columns = Job.columns(**values)
        names = ", ".join(f"{name} = ?" for name in columns)
        self._query(f"UPDATE jobs SET {names} WHERE id = ?", (*columns.values(), job_id))

    def set_state(
        self,
        job_id: str,
        state: JobState,
        *,
        when: tuple = ACTIVE,
        log: str | None = None,
        level: str = "info",
        **values,
    ) -> bool:
        """Move a job to `state` if it is in one of `when`; whether it moved.

        If it moved, `log` (if given) is added to its log at `level` at once: whoever reads
        the new state finds the line.
        """
        columns = Job.columns(**values)
        names = "".join(f", {name} = ?" for name in columns)
        marks = ", ".join("?" for _ in when)
        with self._lock:
            cursor = self._db.execute(
                f"UPDATE jobs SET state = ?{names} WHERE id = ? AND state IN ({marks})",
                (str(state), *columns.values(), job_id, *map(str, when)),
            )
            if cursor.rowcount == 1 and log is not None:
                self._db.execute(_LOG, (job_id, time.time(), level, log))
            return cursor.rowcount == 1

    def active(self) -> int:
        """How many jobs are unfinished (`service.records.ACTIVE`)."""
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

    def next_validating(self) -> Job | None:
        """The oldest job still to validate, or None."""
        jobs = self._jobs(
            "WHERE state = ? ORDER BY submitted, rowid LIMIT 1", (str(JobState.VALIDATING),)
        )
        return jobs[0] if jobs else None

    def recover(self) -> int:
        """Queue again, to resume, the jobs a previous service left running; how many."""
        with self._lock:
            return self._db.execute(
                "UPDATE jobs SET state = ?, interrupted = 1, phase = NULL WHERE state = ?",
                (str(JobState.QUEUED), str(JobState.RUNNING)),
            ).rowcount
