"""The job service's commands: ``serve`` and its clients.

The clients are ``submit``, ``jobs``, ``status``, ``logs`` and ``cancel`` (their arguments
are in `service.cli.parser`). ``submit`` sends a submission id (``--submission-id``, else a
random one) and, if the service's answer is lost (a timeout, a connection reset), sends the
same submission again with it: the service answers the job it accepted, never a second.

The clients find the service at ``--server`` or ``OCEANLIDAR_SERVER`` and send the token of
``--token-file`` or ``OCEANLIDAR_TOKEN``. Exit codes as the rest of the CLI: 0 success, 2
bad input (a sweep or request the service refused, a wrong token, an unknown job), 1
failure (the service unreachable or full, a job that failed or was cancelled).
"""

from __future__ import annotations

import functools
import json
import os
import sys
import time
import urllib.error
import urllib.parse
import urllib.request
import uuid

from service.cli.parser import DEFAULT_SERVER
from service.errors import BadOptionError, InputError
from service.inputs import read_text
from service.records import JobState

__all__ = ["cmd_cancel", "cmd_jobs", "cmd_logs", "cmd_serve", "cmd_status", "cmd_submit"]

TIMEOUT = 30.0
"""Seconds to wait for the service's answer to a request."""
SUBMIT_TRIES = 3
"""Times ``submit`` sends a submission whose answer is lost (the same submission id)."""
FOLLOW_TICK = 1.0
"""Seconds between looks at a job's log for ``logs --follow``."""


class UnavailableError(RuntimeError):
    """The service cannot be reached, or cannot take the request now."""


class LostAnswerError(UnavailableError):
    """The request went out but its answer did not come back (a timeout, a reset)."""


def _token(args) -> str:
    if args.token_file is None:
        return os.environ.get("OCEANLIDAR_TOKEN", "").strip()
    lines = read_text(args.token_file, place=f"--token-file {args.token_file}").split()
    return lines[-1] if lines else ""


def _server(args) -> str:
    """The service's URL: ``--server``, else ``OCEANLIDAR_SERVER``, else `DEFAULT_SERVER`.

    Raises
    ------
    BadOptionError
        If it is not an http:// or https:// URL with a host (named by where it came from).
    """
    base = args.server or os.environ.get("OCEANLIDAR_SERVER") or DEFAULT_SERVER
    try:
        parts = urllib.parse.urlsplit(base)
        usable = parts.scheme in ("http", "https") and bool(parts.hostname)
    except ValueError:  # a malformed address ("http://[::1")
        usable = False
    if not usable:
        place = "--server" if args.server else "OCEANLIDAR_SERVER"
        raise BadOptionError(f"{place} {base!r}: not an http:// or https:// URL")
    return base


def _request(args, method: str, path: str, body: bytes | None = None, *, stream=False):
    """The service's JSON answer (or, with `stream`, the open response).

    Raises
    ------
    InputError
        If the service refused the request as bad (4xx but 429): its message (the
        service's answer names no kind).
    UnavailableError
        If it cannot be reached, is full (429) or failed (5xx); a `LostAnswerError` if
        it did not answer in `TIMEOUT` seconds or dropped the connection.
    """
    base = _server(args)
    request = urllib.request.Request(base.rstrip("/") + path, data=body, method=method)
    if body is not None:  # a sweep (the service refuses the types a web page may post)
        request.add_header("Content-Type", "application/yaml")
    if token := _token(args):
        request.add_header("Authorization", f"Bearer {token}")
    try:
        response = urllib.request.urlopen(request, timeout=None if stream else TIMEOUT)
    except urllib.error.HTTPError as error:
        try:
            message = json.loads(error.read()).get("error", error.reason)
        except ValueError:
            message = error.reason
        if 400 <= error.code < 500 and error.code != 429:
            raise InputError(message) from None
        raise UnavailableError(f"{base}: {error.code} {message}") from None
    except (urllib.error.URLError, OSError) as error:
        reason = getattr(error, "reason", error)
        lost = isinstance(reason, TimeoutError | ConnectionResetError)
        kind = LostAnswerError if lost else UnavailableError
        raise kind(f"cannot reach the service at {base}: {reason}") from None
    if stream:
        return response
    with response:
        return json.loads(response.read())


def _line(job: dict) -> str:
    done, total = job["samples"]["done"], job["samples"]["total"]
    left = f", {job['seconds_left']:.0f} s left" if job.get("seconds_left") is not None else ""
    phase = f", {job['phase']}" if job.get("phase") else ""
    return (
        f"{job['id']}  {job['state']:<9}  {done}/{total} samples{phase}  "
        f"{job['rate']:.2f}/s{left}  "
        f"{job['name']} -> {job['url']}"
    )


def _final(job: dict) -> int:
    for sample, reason in list(job["errors"].items())[:20]:
        print(f"  sample {sample}: {reason}", file=sys.stderr)
    if job["message"]:
        print(f"  {job['message']}", file=sys.stderr)
    if job["state"] == JobState.REJECTED:  # bad input, found in the background
        return 2
    return 1 if job["state"] in (JobState.FAILED, JobState.CANCELLED) else 0


def _client(command):
    """`command`, with the service unreachable or full reported as a failure (exit 1)."""

    @functools.wraps(command)
    def run(args) -> int:
        try:
            return command(args)
        except UnavailableError as error:
            print(f"oceanlidar {args.command}: error: {error}", file=sys.stderr)
            return 1

    return run


@_client
def cmd_submit(args) -> int:
    """Submit a sweep file; print the job's id (a lost answer: the same submission again)."""
    text = read_text(args.sweep, place=args.sweep).encode()
    mode = "resume" if args.resume else "overwrite" if args.overwrite else "new"
    submission_id = args.submission_id or uuid.uuid4().hex
    query = urllib.parse.urlencode({"mode": mode, "submission_id": submission_id})
    for attempt in range(1, SUBMIT_TRIES + 1):
        try:
            job = _request(args, "POST", f"/v1/jobs?{query}", text)
            break
        except LostAnswerError as error:
            if attempt == SUBMIT_TRIES:
                raise
            print(
                f"oceanlidar submit: {error}; sending it again (submission id {submission_id})",
                file=sys.stderr,
            )
            time.sleep(attempt)
    print(job["id"])
    print(_line(job), file=sys.stderr)
    return 0


@_client
def cmd_jobs(args) -> int:
    """List the service's jobs, newest first."""
    query = f"?{urllib.parse.urlencode({'state': args.state})}" if args.state else ""
    for job in _request(args, "GET", f"/v1/jobs{query}")["jobs"]:
        print(_line(job))
    return 0


@_client
def cmd_status(args) -> int:
    """A job's state and progress; ``--watch`` follows its events until it finishes."""
    path = f"/v1/jobs/{urllib.parse.quote(args.id, safe='')}"
    if not args.watch:
        job = _request(args, "GET", path)
        print(_line(job))
        return _final(job)
    job = None
    with _request(args, "GET", f"{path}/events", stream=True) as events:
        for raw in events:
            line = raw.decode().rstrip("\n")
            if line.startswith("data: "):
                job = json.loads(line[6:])
                print(_line(job), flush=True)
    if job is None or not JobState(job["state"]).final:
        raise UnavailableError("the event stream ended before the job finished")
    return _final(job)


@_client
def cmd_logs(args) -> int:
    """A job's log, a line each with its UTC time; ``--follow`` until the job finishes."""
    path = f"/v1/jobs/{urllib.parse.quote(args.id, safe='')}/logs"
    printed = 0
    while True:
        answer = _request(args, "GET", path)
        for line in answer["lines"]:
            if line["seq"] > printed:
                when = time.strftime("%Y-%m-%d %H:%M:%S", time.gmtime(line["time"]))
                print(f"{when} UTC  {line['level']:<7}  {line['message']}", flush=True)
                printed = line["seq"]
        if not args.follow or JobState(answer["state"]).final:
            return 0
        time.sleep(FOLLOW_TICK)


@_client
def cmd_cancel(args) -> int:
    """Cancel a job; wait until its running tasks have stopped."""
    path = f"/v1/jobs/{urllib.parse.quote(args.id, safe='')}"
    job = _request(args, "DELETE", path)
    while job["state"] == JobState.RUNNING:  # cancelling: running tasks stop within seconds
        time.sleep(0.5)
        job = _request(args, "GET", path)
    print(_line(job))
    return 0


def cmd_serve(args) -> int:
    """Run the job service until interrupted or terminated (SIGTERM: exit 0)."""
    from service.cli.run_commands import security, sigterm_raises
    from service.server import serve

    with sigterm_raises(SystemExit):
        return serve(args, security(args))
