"""The batch service's runner: submissions accepted, validated, and worked off on one cluster.

A job is a submitted sweep: its YAML text (never credentials), its owner, its state, its
progress and its log, rows of the job table (`service.table.JobTable`). A submission is
answered at once: its quick checks (`service.admission.admit_header`, the owner of the
store it resumes or replaces, the queue limit, no other unfinished job on its output) pass
and it is accepted ``validating``; one validator thread then checks the whole sweep
(`service.admission.admit_job`: every point, the size limits, what is at the output),
oldest first, and queues or rejects it. A submission may carry the submitter's id
(`SUBMISSION_ID`): the same id from the same owner answers the same job again, so a client
may retry a submission whose answer it lost.

The table is the service's memory across restarts: a job found ``running`` when the service
starts was interrupted (a crash, a kill) and is run again with resume, so it completes from
its store with the same bytes as an undisturbed run; queued jobs stay queued and
``validating`` ones are validated again.

Several jobs run at once on the one dask client. Each keeps a bounded window of tasks in
flight (`service.run.run_plan`) and the scheduler starts tasks in submission order, so the
jobs running take turns on the workers: none starves another.
"""

from __future__ import annotations

import re
import threading
import time
import uuid

from service.admission import SERVICE, admit_header, admit_job, confine_output, parents
from service.devices import NUMPY
from service.errors import (
    BadOptionError,
    InputError,
    OutputTakenError,
    SubmissionConflictError,
)
from service.inputs import shown
from service.records import ACTIVE, WRITING_STATISTICS, Job, JobState
from service.run import Cancel, execute
from service.store.template import OWNER
from service.sweep import parse_sweep

__all__ = [
    "SUBMISSION_ID",
    "ForbiddenError",
    "QueueFullError",
    "Runner",
]

DISPATCH_TICK = 0.2
"""Seconds between looks for queued jobs to start (and for jobs to validate)."""
MILESTONES = 10
"""Progress lines a job's log holds (one each tenth of its samples)."""
SUBMISSION_ID = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]{0,63}")
"""A submission id: 1 to 64 letters, digits, ``.``, ``_`` or ``-``, the first a letter or digit."""


class QueueFullError(RuntimeError):
    """The service holds as many unfinished jobs as its queue limit allows."""


class ForbiddenError(RuntimeError):
    """A submitter acts on another owner's job or store."""


class _JobCancel(Cancel):
    """A job's `Cancel`, which marks the job `WRITING_STATISTICS` as the run closes it.

    The run closes it once its samples are written; the phase is then in the table, for
    the API, the job page and ``oceanlidar status``.
    """

    def __init__(self, table, job_id: str):
        super().__init__()
        self.table, self.job_id = table, job_id

    def close(self) -> bool:
        closed = super().close()
        if closed:
            self.table.update(self.job_id, phase=WRITING_STATISTICS)
            self.table.log(self.job_id, "every sample written: writing the statistics")
        return closed


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
    backend : Backend, optional
        Where every job's samples render (``serve --backend --device``): a job resuming a
        store rendered elsewhere is rejected (`service.devices.check_same`).
    batch_memory : float or None, optional
        Bytes a task's batch may take (``serve --batch-memory``); None: a share of its
        device's memory (`service.batching.memory_budget`).
    """

    def __init__(
        self,
        table,
        client,
        *,
        data_root,
        max_running,
        queue_limit,
        batch_size,
        backend=NUMPY,
        batch_memory=None,
    ):
        self.table, self.client, self.data_root = table, client, data_root
        self.backend, self.batch_memory = backend, batch_memory
        self.max_running, self.queue_limit, self.batch_size = max_running, queue_limit, batch_size
        self._running: dict[str, tuple[threading.Thread, Cancel]] = {}
        self._stop = threading.Event()
        self._admit = threading.Lock()
        self._wake = threading.Event()
        self._dispatcher = threading.Thread(target=self._dispatch, name="jobs", daemon=True)
        self._validator = threading.Thread(target=self._validate, name="validate", daemon=True)

    def start(self) -> None:
        """Requeue interrupted jobs and start validating and working the queue."""
        self.table.recover()
        self._validator.start()
        self._dispatcher.start()

    def stop(self) -> None:
        """Stop running jobs resumably (they stay ``running`` and resume at the next start)."""
        self._stop.set()
        self._wake.set()
        for _, cancel in list(self._running.values()):
            cancel.set()
        for thread, _ in list(self._running.values()):
            thread.join(timeout=30)
        self._dispatcher.join(timeout=5)
        self._validator.join(timeout=5)

    def submit(
        self, text: str, *, owner: str, mode: str = "new", submission_id: str | None = None
    ) -> tuple[Job, bool]:
        """Accept a sweep to validate in the background (``validating``), after its quick checks.

        The quick checks are `admit_header`'s (the sweep's file, its output under the data
        root), the owner of a store it resumes or overwrites, the queue limit and the
        outputs of the unfinished jobs; `admit_job`'s, which grow with the sweep, follow in
        the validator thread, which queues the job or rejects it (`JobState`).

        Parameters
        ----------
        text : str
            The sweep's YAML text.
        owner : str
            Who submits it.
        mode : str, optional
            ``new``, ``resume`` or ``overwrite`` (`service.admission.MODES`).
        submission_id : str or None, optional
            The submitter's id of this submission (`SUBMISSION_ID`): a job `owner`
            submitted with it before is answered again, not a second one.

        Returns
        -------
        tuple of (Job, bool)
            The job, and whether it is new (False: the submission id's earlier job).

        Raises
        ------
        InputError
            For a bad submission id, sweep or mode, or an output this job may not write
            (another unfinished job writes it: `OutputTakenError`); one of them:
        SubmissionConflictError
            If `submission_id` names a job of `owner` with another sweep text or mode.
        ForbiddenError
            If a resume or an overwrite names a store another owner wrote: the store's
            own record (`service.store.template.OWNER`) says who, else the job table's
            newest job into it; a store that records no owner is nobody's to replace.
        QueueFullError
            If `queue_limit` jobs are unfinished.
        """
        if submission_id is not None and not SUBMISSION_ID.fullmatch(submission_id):
            raise BadOptionError(
                "submission_id: 1 to 64 letters, digits, '.', '_' or '-', the first a letter "
                f"or digit, got {shown(submission_id)}"
            )
        with self._admit:
            if submission_id is not None:
                if known := self.table.submission(owner, submission_id):
                    if (known.sweep, known.mode) != (text, mode):
                        raise SubmissionConflictError(
                            f"submission_id {submission_id}: already names job {known.id}, "
                            "of another sweep or mode; choose a new id"
                        )
                    return known, False
            sweep, url = admit_header(text, mode, data_root=self.data_root)
            store = self.data_root.other(url)
            with store.errors():
                attributes = store.attributes()
                taken = attributes is not None or store.occupied()
            previous = self.table.latest(url)
            wrote = (attributes or {}).get(OWNER, previous.owner if previous else None)
            who = f"was written by {wrote}" if wrote else "records no owner"
            if taken and mode == "new":  # answered now (409), with the remedy this owner has
                remedy = SERVICE.exists if wrote == owner else f"it {who}: choose another output"
                raise OutputTakenError(f"output: {shown(sweep.output)} already exists; {remedy}")
            if attributes is not None and wrote != owner:  # a store is there
                raise ForbiddenError(
                    f"output: {shown(sweep.output)} {who}; only its owner may {mode} it"
                )
            if self.table.active() >= self.queue_limit:
                raise QueueFullError(
                    f"{self.queue_limit} jobs are validating, queued or running; try later"
                )
            for job in (job for state in ACTIVE for job in self.table.list(state)):
                if url in (job.url, *parents(job.url)) or job.url in parents(url):
                    raise OutputTakenError(
                        f"output: job {job.id} writes {shown(job.url)}, the same store "
                        "or one inside the other"
                    )
            job = Job(
                id=uuid.uuid4().hex[:12],
                owner=owner,
                name=sweep.name,
                state=JobState.VALIDATING,
                mode=mode,
                sweep=text,
                output=sweep.output,
                url=url,
                submitted=time.time(),
                total=0,
                submission_id=submission_id,
            )
            self.table.add(job)
            given = f", submission id {submission_id}" if submission_id else ""
            self.table.log(job.id, f"accepted from {owner} (mode {mode}{given})")
        self._wake.set()
        return job, True

    def cancel(self, job_id: str) -> bool:
        """Cancel a job not yet finished; False if it had finished or writes its statistics."""
        if self.table.set_state(
            job_id,
            JobState.CANCELLED,
            when=(JobState.VALIDATING, JobState.QUEUED),
            finished=time.time(),
            log="cancelled before it started",
        ):
            return True
        entry = self._running.get(job_id)
        if entry is None or not entry[1].cancel():
            return False
        self.table.log(job_id, "cancel asked: the running tasks stop")
        return True

    def _validate(self) -> None:
        """Check the ``validating`` jobs whole, oldest first, one at a time (`admit_job`)."""
        while not self._stop.is_set():
            job = None if self.table.lost() else self.table.next_validating()
            if job is None:
                self._wake.wait(DISPATCH_TICK)
                self._wake.clear()
                continue
            self.table.log(job.id, "validating: every parameter point, the limits, the output")
            try:
                plan, _ = admit_job(
                    job.sweep, job.mode, data_root=self.data_root, backend=self.backend
                )
            except Exception as error:  # a job's failure must not take the service down
                bad = isinstance(error, InputError)
                self.table.set_state(
                    job.id,
                    JobState.REJECTED if bad else JobState.FAILED,
                    when=(JobState.VALIDATING,),
                    finished=time.time(),
                    message=str(error) if bad else repr(error),
                    log=f"{'rejected' if bad else 'failed to validate'}: {error}",
                    level="error",
                )
                continue
            self.table.set_state(
                job.id,
                JobState.QUEUED,
                when=(JobState.VALIDATING,),
                total=plan.samples,
                log=f"queued: {len(plan.points)} parameter points x {plan.realisations} "
                f"realisations = {plan.samples} samples",
            )

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
            if job is None:
                continue
            again = " again, resuming its store (the service had stopped)" * job.interrupted
            if not self.table.set_state(
                job.id,
                JobState.RUNNING,
                when=(JobState.QUEUED,),
                started=time.time(),
                log=f"started{again}",
            ):
                continue
            cancel = _JobCancel(self.table, job.id)
            thread = threading.Thread(
                target=self._run, args=(job, cancel), name=f"job-{job.id}", daemon=True
            )
            self._running[job.id] = (thread, cancel)
            thread.start()

    def _run(self, job: Job, cancel: Cancel) -> None:
        milestone = [0]  # the last tenth of the samples the log has told

        def progress(done: int, rate: float) -> None:
            self.table.update(job.id, done=done, rate=rate)
            if job.total and (tenth := done * MILESTONES // job.total) > milestone[0]:
                milestone[0] = tenth
                self.table.log(job.id, f"{done}/{job.total} samples written, {rate:.2f}/s")

        try:
            # a symbolic link planted in the data root since the job was admitted could
            # lead its output out of it: the output is confined again as it starts
            confine_output(job.output, self.data_root.url)
            plan = parse_sweep(job.sweep, folder=self.data_root.url, max_memory=None)
            store = self.data_root.other(job.url)
            # an interrupted job resumes its own store (this sweep's, by its hash); one that
            # was stopped before it made it (an overwrite that had not yet deleted the old
            # store) starts as it was asked
            attributes = store.attributes() or {}
            resume = job.mode == "resume" or (
                job.interrupted and attributes.get("sweep_sha256") == plan.digest
            )
            result = execute(
                plan,
                store,
                client=self.client,
                resume=resume,
                overwrite=job.mode == "overwrite" and not resume,
                batch_size=self.batch_size,
                cancel=cancel,
                on_progress=progress,
                claim=f"oceanlidar service job {job.id}",
                owner=job.owner,
                backend=self.backend,
                batch_memory=self.batch_memory,
            )
        except Exception as error:  # a job's failure must not take the service down
            message = str(error) if isinstance(error, InputError) else repr(error)
            self.table.set_state(
                job.id,
                JobState.FAILED,
                finished=time.time(),
                message=message,
                phase=None,
                log=f"failed: {message}",
                level="error",
            )
            return
        errors = {
            str(sample): reason
            for samples in result.problems().values()
            for sample, reason in samples
        }
        finished = {"errors": errors, "finished": time.time(), "phase": None}
        for kind, samples in result.problems().items():
            sample, reason = samples[0]
            self.table.log(
                job.id,
                f"{len(samples)} samples {kind}; sample {sample}: {reason}",
                level="warning",
            )
        if result.interrupted:
            if self._stop.is_set():  # the service stops: resume at its next start
                self.table.update(job.id, interrupted=True)
                self.table.log(job.id, "the service stops: it resumes at its next start")
                return
            done = int(store.completed().sum())
            message = "cancelled; submit it again with resume to complete it"
            self.table.set_state(
                job.id,
                JobState.CANCELLED,
                message=message,
                done=done,
                log=f"{message} ({done}/{plan.samples} samples written)",
                level="warning",
                **finished,
            )
        elif errors or result.stopped:
            problems = [plan.sample(int(s)).describe() for s in list(errors)[:3]]
            message = result.stopped or "failed: " + "; ".join(problems)
            self.table.set_state(
                job.id, JobState.FAILED, message=message, log=message, level="error", **finished
            )
        else:
            self.table.set_state(
                job.id,
                JobState.SUCCEEDED,
                done=plan.samples,
                log=f"succeeded: {plan.samples} samples and their statistics written",
                **finished,
            )
