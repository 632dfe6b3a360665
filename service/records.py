"""The service's records: a job of the job service (`Job`, `JobState`) and a run (`RunResult`).

A job is a row of the job table (`service.table.JobTable`) read into a `Job`; what the API
shows of it is `Job.public` (the JSON of ``/v1/jobs``). A run's outcome is a `RunResult`
(`service.run.execute`); its `RunResult.problems` is the one report of the samples it could
not write, printed by ``oceanlidar run`` and stored as a job's ``errors``.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from enum import StrEnum
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import numpy as np

__all__ = ["ACTIVE", "WRITING_STATISTICS", "Job", "JobState", "RunResult"]


class JobState(StrEnum):
    """Where a job is: checked, waiting, running, or finished one of four ways.

    A submission is accepted ``validating`` (its quick checks passed) and its whole sweep
    checked in the background: then ``queued``, or ``rejected`` (bad input, the reason in
    its message; nothing written). The values are the API's state strings and the job
    table's.
    """

    VALIDATING = "validating"
    QUEUED = "queued"
    RUNNING = "running"
    SUCCEEDED = "succeeded"
    FAILED = "failed"
    CANCELLED = "cancelled"
    REJECTED = "rejected"

    @property
    def final(self) -> bool:
        """Whether the job has finished (it moves no more)."""
        return self not in ACTIVE


ACTIVE = (JobState.VALIDATING, JobState.QUEUED, JobState.RUNNING)
"""The states of unfinished jobs (each holds its output: no other job may write it)."""
WRITING_STATISTICS = "writing statistics"
"""The phase of a running job whose samples are all written (`Job.phase`): it can no longer
be cancelled, and ends when its statistics are written."""


@dataclass
class Job:
    """One submitted sweep: its text (never credentials), owner, state and progress.

    Attributes
    ----------
    id, owner, name : str
        The job's id, who submitted it, and its sweep's name.
    state : JobState
    mode : str
        ``new``, ``resume`` or ``overwrite`` (`service.admission.MODES`).
    sweep : str
        The sweep's YAML text as submitted.
    output, url : str
        The sweep's output as written, and the store it names under the data root.
    submitted, started, finished : float or None
        Seconds since the epoch.
    total, done : int
        Samples of the sweep (0 until it is validated), and samples complete.
    rate : float
        Samples a second of the run.
    message : str or None
        Why it was rejected, failed or was cancelled.
    errors : dict
        The reason of each sample not written, by sample (`RunResult.problems`).
    interrupted : bool
        Whether a service stopped while it ran (it resumes at the next start).
    submission_id : str or None
        The submitter's id of the submission (`service.jobs.SUBMISSION_ID`): the same id
        from the same owner answers this job again.
    phase : str or None
        What a running job does, if not rendering samples: `WRITING_STATISTICS`.
    """

    id: str
    owner: str
    name: str
    state: JobState
    mode: str
    sweep: str
    output: str
    url: str
    submitted: float
    total: int
    started: float | None = None
    finished: float | None = None
    done: int = 0
    rate: float = 0.0
    message: str | None = None
    errors: dict[str, str] = field(default_factory=dict)
    interrupted: bool = False
    submission_id: str | None = None
    phase: str | None = None

    @classmethod
    def from_row(cls, row: dict) -> Job:
        """The job of a job-table row (its columns by name)."""
        return cls(
            **{
                **row,
                "state": JobState(row["state"]),
                "errors": json.loads(row["errors"]),
                "interrupted": bool(row["interrupted"]),
            }
        )

    def row(self) -> dict:
        """The job-table row of this job, its columns by name."""
        return self.columns(**vars(self))

    @staticmethod
    def columns(**values) -> dict:
        """Job fields by name as the job table's columns hold them (JSON, integers)."""
        converters = {"state": str, "errors": json.dumps, "interrupted": int}
        return {
            name: converters.get(name, lambda value: value)(value)
            for name, value in values.items()
        }

    def public(self) -> dict:
        """The job as the API shows it."""
        left = (self.total - self.done) / self.rate if self.rate > 0 else None
        return {
            "id": self.id,
            "name": self.name,
            "owner": self.owner,
            "state": self.state.value,
            "mode": self.mode,
            "output": self.output,
            "submitted": self.submitted,
            "started": self.started,
            "finished": self.finished,
            "url": self.url,
            "samples": {"done": self.done, "total": self.total},
            "rate": self.rate,
            "seconds_left": left if self.state is JobState.RUNNING else None,
            "message": self.message,
            "resumed": self.interrupted,
            "errors": self.errors,
            "submission_id": self.submission_id,
            "phase": self.phase,
        }


@dataclass
class RunResult:
    """What a run did.

    ``failed`` holds ``(start, count, error)`` for tasks that raised or lost their worker;
    ``refused`` holds ``(sample, reason)`` for samples whose scene cannot be rendered
    (`workers.settings.section.SceneError`: bad input, not retried); ``rejected`` holds
    ``(sample, reason)`` for samples rendered with invalid values
    (`service.store.integrity.invalid_values`); neither are written nor marked complete;
    ``damaged`` holds ``(sample, reason)`` for samples that ``verify`` found damaged and
    recomputed; ``relabelled`` names the labels and coordinates it found wrong and wrote again;
    ``stuck`` holds ``(start, count)`` for tasks given up `task_timeout` seconds after
    their submission; ``unwritten`` holds ``(sample, reason)`` for samples not marked
    complete when the run ends without another failure (a fault of the runner: no
    statistics are written over them); ``stopped`` says why a run stopped early (a storage
    failure no retry cures); ``points`` holds the parameter points whose samples a resumed
    run (re)wrote (None: all).
    """

    total: int
    task_timeout: float
    written: int = 0
    skipped: int = 0
    failed: list = field(default_factory=list)
    refused: list = field(default_factory=list)
    rejected: list = field(default_factory=list)
    damaged: list = field(default_factory=list)
    relabelled: list = field(default_factory=list)
    stuck: list = field(default_factory=list)
    unwritten: list = field(default_factory=list)
    stopped: str | None = None
    seconds: float = 0.0
    interrupted: bool = False
    max_in_flight: int = 0
    points: np.ndarray | None = None

    @property
    def ok(self) -> bool:
        """Whether every sample was written: nothing interrupted, failed, refused or stopped."""
        return not (
            self.interrupted
            or self.failed
            or self.refused
            or self.rejected
            or self.stuck
            or self.unwritten
            or self.stopped
        )

    def problems(self) -> dict[str, list[tuple[int, str]]]:
        """The samples not written, ``(sample, reason)``, by what happened to them.

        Five kinds, in this order: refused (a scene that cannot be rendered), not stored
        (invalid values), failed (a task that raised or lost its worker), stuck (a task
        given up), unwritten (not marked complete, with no failure to say why); a kind with
        no sample is left out. A run that `stopped` or was interrupted may have left samples
        unwritten that are none of these.
        """
        stuck = f"no result {self.task_timeout:g} s after submission (a frozen worker?); given up"
        kinds = {
            "refused (bad input, not retried)": self.refused,
            "not stored": self.rejected,
            "failed": [
                (sample, error)
                for start, count, error in self.failed
                for sample in range(start, start + count)
            ],
            "stuck": [
                (sample, stuck)
                for start, count in self.stuck
                for sample in range(start, start + count)
            ],
            "unwritten": self.unwritten,
        }
        return {kind: samples for kind, samples in kinds.items() if samples}
