"""The batch service on the command line: ``serve`` and its clients.

The clients are ``submit``, ``jobs``, ``status`` and ``cancel``.

The clients find the service at ``--server`` or ``OCEANLIDAR_SERVER`` and send the token of
``--token-file`` or ``OCEANLIDAR_TOKEN``. Exit codes as the rest of the CLI: 0 success, 2
bad input (a sweep or request the service refused, a wrong token, an unknown job), 1
failure (the service unreachable or full, a job that failed or was cancelled).
"""

from __future__ import annotations

import json
import os
import sys
import time
import urllib.error
import urllib.parse
import urllib.request

from service.inputs import SweepError, json_object, read_text

__all__ = ["COMMANDS", "add_commands"]

DEFAULT_SERVER = "http://127.0.0.1:8000"
TIMEOUT = 30.0
"""Seconds to wait for the service's answer to a request."""


class UnavailableError(RuntimeError):
    """The service cannot be reached, or cannot take the request now."""


def add_commands(commands) -> None:
    """Add ``serve``, ``submit``, ``jobs``, ``status`` and ``cancel`` to `commands`."""
    serve = commands.add_parser("serve", help="run the batch service (HTTP API and web page)")
    serve.add_argument(
        "--host", default="127.0.0.1", help="address to listen on (default: %(default)s)"
    )
    serve.add_argument("--port", type=int, default=8000, help="port (default: %(default)s)")
    serve.add_argument("--db", default="oceanlidar-jobs.sqlite", help="job table, SQLite file")
    serve.add_argument(
        "--data-root",
        default="oceanlidar-data",
        help="folder or URL prefix that every job's output lies under (default: %(default)s)",
    )
    serve.add_argument("--storage-options", type=json_object, help="data root's fsspec options")
    serve.add_argument("--token-file", help="tokens, 'OWNER TOKEN' a line (else OCEANLIDAR_TOKEN)")
    serve.add_argument("--no-auth", action="store_true", help="no token (127.0.0.1 only)")
    serve.add_argument("--max-running", type=int, default=4, help="jobs run at once (default 4)")
    serve.add_argument(
        "--queue-limit", type=int, default=100, help="most unfinished jobs (default 100)"
    )
    serve.add_argument(
        "--batch",
        type=int,
        default=None,
        help="samples per shard and task of a new store (default: as many as fit in "
        "16 MiB uncompressed, at most 256, leaving at least 8 shards)",
    )
    where = serve.add_mutually_exclusive_group()
    where.add_argument("--workers", type=int, default=None, help="embedded cluster's workers")
    where.add_argument("--scheduler", help="address of an existing dask scheduler")
    tls = serve.add_argument_group("TLS (for tls:// schedulers; else dask's configuration)")
    tls.add_argument("--tls-ca-file", help="CA certificate(s), PEM")
    tls.add_argument("--tls-cert", help="client certificate, PEM")
    tls.add_argument("--tls-key", help="client private key, PEM")

    submit = commands.add_parser("submit", help="submit a sweep to the service")
    submit.add_argument("sweep", help="sweep YAML file")
    mode = submit.add_mutually_exclusive_group()
    mode.add_argument("--resume", action="store_true", help="complete an existing store")
    mode.add_argument("--overwrite", action="store_true", help="replace an existing store")
    jobs = commands.add_parser("jobs", help="list the service's jobs, newest first")
    jobs.add_argument("--state", help="only jobs in this state")
    status = commands.add_parser("status", help="a job's state and progress")
    status.add_argument("id", help="job id")
    status.add_argument("--watch", action="store_true", help="follow it until it finishes")
    cancel = commands.add_parser("cancel", help="cancel a job (its store stays resumable)")
    cancel.add_argument("id", help="job id")
    for parser in (submit, jobs, status, cancel):
        parser.add_argument(
            "--server", help=f"service URL (else OCEANLIDAR_SERVER, {DEFAULT_SERVER})"
        )
        parser.add_argument("--token-file", help="file holding the token (else OCEANLIDAR_TOKEN)")


def _token(args) -> str:
    if args.token_file is None:
        return os.environ.get("OCEANLIDAR_TOKEN", "").strip()
    lines = read_text(args.token_file, place=f"--token-file {args.token_file}").split()
    return lines[-1] if lines else ""


def _request(args, method: str, path: str, body: bytes | None = None, *, stream=False):
    """The service's JSON answer (or, with `stream`, the open response).

    Raises
    ------
    SweepError
        If the service refused the request as bad (4xx but 429): its message.
    UnavailableError
        If it cannot be reached, is full (429) or failed (5xx).
    """
    base = args.server or os.environ.get("OCEANLIDAR_SERVER") or DEFAULT_SERVER
    request = urllib.request.Request(base.rstrip("/") + path, data=body, method=method)
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
            raise SweepError(message) from None
        raise UnavailableError(f"{base}: {error.code} {message}") from None
    except (urllib.error.URLError, OSError) as error:
        reason = getattr(error, "reason", error)
        raise UnavailableError(f"cannot reach the service at {base}: {reason}") from None
    if stream:
        return response
    with response:
        return json.loads(response.read())


def _line(job: dict) -> str:
    done, total = job["samples"]["done"], job["samples"]["total"]
    left = f", {job['seconds_left']:.0f} s left" if job.get("seconds_left") is not None else ""
    return (
        f"{job['id']}  {job['state']:<9}  {done}/{total} samples  {job['rate']:.2f}/s{left}  "
        f"{job['name']} -> {job['url']}"
    )


def _final(job: dict) -> int:
    for sample, reason in list(job["errors"].items())[:20]:
        print(f"  sample {sample}: {reason}", file=sys.stderr)
    if job["message"]:
        print(f"  {job['message']}", file=sys.stderr)
    return 1 if job["state"] in ("failed", "cancelled") else 0


def _cmd_submit(args) -> int:
    text = read_text(args.sweep, place=args.sweep).encode()
    mode = "resume" if args.resume else "overwrite" if args.overwrite else "new"
    job = _request(args, "POST", f"/v1/jobs?mode={mode}", text)
    print(job["id"])
    print(_line(job), file=sys.stderr)
    return 0


def _cmd_jobs(args) -> int:
    query = f"?{urllib.parse.urlencode({'state': args.state})}" if args.state else ""
    for job in _request(args, "GET", f"/v1/jobs{query}")["jobs"]:
        print(_line(job))
    return 0


def _cmd_status(args) -> int:
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
    if job is None or job["state"] not in ("succeeded", "failed", "cancelled"):
        raise UnavailableError("the event stream ended before the job finished")
    return _final(job)


def _cmd_cancel(args) -> int:
    path = f"/v1/jobs/{urllib.parse.quote(args.id, safe='')}"
    job = _request(args, "DELETE", path)
    while job["state"] == "running":  # cancelling: running tasks stop within seconds
        time.sleep(0.5)
        job = _request(args, "GET", path)
    print(_line(job))
    return 0


def _cmd_serve(args) -> int:
    from service.run_commands import security
    from service.server import serve

    return serve(args, security(args))


def _client(command):
    def run(args) -> int:
        try:
            return command(args)
        except UnavailableError as error:
            print(f"oceanlidar {args.command}: error: {error}", file=sys.stderr)
            return 1

    return run


COMMANDS = {
    "serve": _cmd_serve,
    **{
        name: _client(command)
        for name, command in [
            ("submit", _cmd_submit),
            ("jobs", _cmd_jobs),
            ("status", _cmd_status),
            ("cancel", _cmd_cancel),
        ]
    },
}
"""The handlers of the commands `add_commands` adds, by name."""
