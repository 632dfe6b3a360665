"""``oceanlidar serve``: the batch service's HTTP API and web page (Starlette on uvicorn).

The API is JSON under ``/v1`` (see README, "Running the service"); the page at ``/`` lists
the jobs with their progress and shows one job's sweep, statistics plot and preview strip
(`service.pages`). Every route but ``/v1/health``, ``/login`` and the pages' script needs
the service's token: an ``Authorization: Bearer TOKEN`` header, or, for reading (``GET``)
alone, the cookie that ``/login`` sets for browsers: a request that changes something (a
submission, a cancel) needs the header, which another site's page cannot make a browser
send (no cross-site request forgery through the cookie). The one exception, a job page's
cancel form (``POST /jobs/ID/cancel``), carries a token derived from the cookie that only
the service's own pages hold (`service.pages.csrf_token`), and is refused from another
origin. Every answer forbids framing, sniffing and anything the pages do not load from the
service itself (`service.guards.SECURITY_HEADERS`). No request that changes something is
taken from another site's page: a foreign ``Origin`` is refused, and a submission must
carry a type no page may post unasked (`SWEEP_TYPES`); a service without tokens answers a
loopback ``Host`` alone (`service.guards.loopback_only`: DNS rebinding). Connections are
bounded in number and in the time they take to send their headers
(`service.connections.Connection`). A service whose job table was lost (the file deleted,
replaced, overwritten or truncated while it serves) answers ``503`` everywhere, health
included.
"""

from __future__ import annotations

import asyncio
import functools
import hmac
import html
import json
import os
import secrets
import socket
import sys

import uvicorn
from starlette.applications import Starlette
from starlette.concurrency import run_in_threadpool
from starlette.requests import ClientDisconnect, Request
from starlette.responses import (
    HTMLResponse,
    JSONResponse,
    RedirectResponse,
    Response,
    StreamingResponse,
)
from starlette.routing import Route

from service import package_version
from service.batching import given_memory
from service.cluster import dask_client
from service.connections import Connection, Server, connection_limit
from service.devices import choose
from service.errors import BadOptionError, InputError
from service.guards import LOOPBACK, loopback_only, read_tokens, secured
from service.inputs import MAX_FILE_BYTES
from service.jobs import ForbiddenError, QueueFullError, Runner
from service.pages import (
    LOGIN_FORM,
    SCRIPT,
    csrf_token,
    job_page,
    list_page,
    page,
    read_form,
    same_origin,
)
from service.pictures import KINDS, Pictures
from service.records import JobState
from service.store.location import Store
from service.table import JobTable

__all__ = ["create_app", "serve"]

COOKIE = "oceanlidar_token"
EVENT_TICK = 0.5
"""Seconds between looks at a job for its event stream."""
SAFE_METHODS = ("GET", "HEAD")
"""Requests the login cookie may authenticate: they read, never change anything."""
SWEEP_TYPES = (
    "application/yaml",
    "application/x-yaml",
    "text/yaml",
    "text/x-yaml",
    "application/json",
)
"""The ``Content-Type``s a submission may carry: none is one a page of another site may send
without the browser asking the service first (a CORS preflight, which it does not answer)."""


def _error(status: int, message: str) -> JSONResponse:
    return JSONResponse({"error": message}, status_code=status)


class _Service:
    """The routes, over one runner and its table."""

    def __init__(self, runner: Runner, tokens: dict[str, str]):
        self.runner, self.table, self.tokens = runner, runner.table, tokens
        self.pictures = Pictures(runner.data_root)
        self.secret = secrets.token_bytes(32)
        """The key of the pages' cancel forms (`service.pages.csrf_token`)."""

    def owner(self, request: Request, given: str | None = None) -> str | None:
        """Who sent `request` (by its token, or the token `given`), or None if nobody known."""
        if not self.tokens:
            return "anonymous"
        if given is None:
            header = request.headers.get("authorization", "")
            given = header[7:] if header.lower().startswith("bearer ") else ""
            if request.method in SAFE_METHODS:
                given = given or request.cookies.get(COOKIE, "")
        for owner, token in self.tokens.items():
            if given and hmac.compare_digest(given.encode(), token.encode()):
                return owner
        return None

    def routes(self) -> list[Route]:
        guarded = [
            ("/v1/jobs", self.submit, "POST"),
            ("/v1/jobs", self.jobs, "GET"),
            ("/v1/jobs/{id}", self.job, "GET"),
            ("/v1/jobs/{id}", self.cancel, "DELETE"),
            ("/v1/jobs/{id}/events", self.events, "GET"),
            ("/v1/jobs/{id}/logs", self.logs, "GET"),
            ("/", self.page_list, "GET"),
            ("/jobs/{id}", self.page_job, "GET"),
            ("/jobs/{id}/{picture}.png", self.picture, "GET"),
        ]
        return [
            Route("/v1/health", self.health, methods=["GET"]),
            Route("/login", self.login, methods=["GET", "POST"]),
            Route("/job.js", self.script, methods=["GET"]),
            Route("/jobs/{id}/cancel", self.page_cancel, methods=["POST"]),
            *[Route(path, self._guard(fn), methods=[method]) for path, fn, method in guarded],
        ]

    def _guard(self, endpoint):
        async def guarded(request: Request):
            if lost := self.table.lost():
                return _error(503, f"{lost}: restart the service on its table")
            if request.method not in SAFE_METHODS and not same_origin(
                request.headers, required=False
            ):
                return _error(403, "a request from another site's page is refused")
            request.state.owner = self.owner(request)
            if request.state.owner is not None:
                return await endpoint(request)
            if request.url.path.startswith("/v1/"):
                return _error(401, "a valid token is needed: Authorization: Bearer TOKEN")
            return RedirectResponse("/login", status_code=303)

        return guarded

    async def health(self, request: Request) -> JSONResponse:
        if lost := self.table.lost():
            return JSONResponse({"status": "failing", "error": lost}, status_code=503)
        return JSONResponse({"status": "ok", "version": package_version()})

    async def login(self, request: Request) -> Response:
        if request.method == "POST":
            form = await read_form(request)
            if isinstance(form, Response):
                return form
            token = form.get("token", "")
            if self.owner(request, given=token) is None:
                return HTMLResponse(page("oceanlidar: log in", LOGIN_FORM), status_code=401)
            response = RedirectResponse("/", status_code=303)
            secure = request.headers.get("x-forwarded-proto", request.url.scheme) == "https"
            response.set_cookie(COOKIE, token, httponly=True, samesite="strict", secure=secure)
            return response
        return HTMLResponse(page("oceanlidar: log in", LOGIN_FORM))

    async def script(self, request: Request) -> Response:
        return Response(SCRIPT, media_type="text/javascript")

    async def submit(self, request: Request) -> JSONResponse:
        kind = request.headers.get("content-type", "").partition(";")[0].strip().lower()
        if kind not in SWEEP_TYPES:
            return _error(
                415,
                f"Content-Type {kind or '(none)'}: send the sweep as application/yaml (or "
                f"one of {', '.join(SWEEP_TYPES[1:])})",
            )
        if any(len(request.query_params.getlist(n)) > 1 for n in ("mode", "submission_id")):
            return _error(400, "mode and submission_id: each may be given once")
        body = b""
        try:
            async for chunk in request.stream():
                body += chunk
                if len(body) > MAX_FILE_BYTES:
                    return _error(413, f"the sweep is larger than {MAX_FILE_BYTES:,} bytes")
        except ClientDisconnect:  # nobody to answer: nothing submitted
            return _error(400, "the client went away before the whole sweep was sent")
        try:
            text = body.decode("utf-8")
        except UnicodeDecodeError:
            return _error(400, "the sweep is not UTF-8 text")
        mode = request.query_params.get("mode", "new")
        submission_id = request.query_params.get("submission_id")
        try:
            job, new = await run_in_threadpool(
                self.runner.submit,
                text,
                owner=request.state.owner,
                mode=mode,
                submission_id=submission_id,
            )
        except InputError as error:
            return _error(error.status, str(error))
        except ForbiddenError as error:
            return _error(403, str(error))
        except QueueFullError as error:
            return _error(429, str(error))
        return JSONResponse(job.public(), status_code=201 if new else 200)

    async def jobs(self, request: Request) -> JSONResponse:
        state = request.query_params.get("state")
        states = [str(known) for known in JobState]
        if state is not None and state not in states:
            return _error(400, f"state {state!r}: not one of {', '.join(states)}")
        return JSONResponse({"jobs": [job.public() for job in self.table.list(state)]})

    async def job(self, request: Request) -> JSONResponse:
        job = self.table.get(request.path_params["id"])
        return JSONResponse(job.public()) if job else _error(404, "no such job")

    def _cancel(self, job_id: str, owner: str) -> tuple[int, str]:
        """Cancel `job_id` for `owner`: (200, "") or the refusal's (status, reason)."""
        job = self.table.get(job_id)
        if job is None:
            return 404, "no such job"
        if job.owner != owner:
            return 403, f"job {job_id} is {job.owner}'s: only its owner may cancel it"
        if not self.runner.cancel(job_id):
            return 409, (
                f"job {job_id} has finished or is writing its statistics: it can no longer "
                "be cancelled"
            )
        return 200, ""

    async def cancel(self, request: Request) -> JSONResponse:
        job_id = request.path_params["id"]
        status, reason = self._cancel(job_id, request.state.owner)
        if reason:
            return _error(status, reason)
        return JSONResponse(self.table.get(job_id).public())

    async def page_cancel(self, request: Request) -> Response:
        """A job page's cancel form: the cookie's owner, the form's token, this origin only."""
        job_id = request.path_params["id"]
        if lost := self.table.lost():
            return _error(503, f"{lost}: restart the service on its table")
        if not same_origin(request.headers):
            return _refused(403, "a cancel from another site's page is refused")
        credential = request.cookies.get(COOKIE, "")
        owner = self.owner(request, given=credential)
        if owner is None:
            return RedirectResponse("/login", status_code=303)
        form = await read_form(request)
        if isinstance(form, Response):
            return form
        expected = csrf_token(self.secret, credential)
        if not hmac.compare_digest(form.get("csrf", "").encode(), expected.encode()):
            return _refused(403, "the form is not this service's page's: reload the job page")
        status, reason = self._cancel(job_id, owner)
        if reason:
            return _refused(status, reason)
        return RedirectResponse(f"/jobs/{job_id}", status_code=303)

    async def events(self, request: Request) -> Response:
        job_id = request.path_params["id"]
        if self.table.get(job_id) is None:
            return _error(404, "no such job")

        async def stream():
            last = None
            while True:
                job = self.table.get(job_id)
                shown = job.public()
                if shown != last:
                    yield f"event: progress\ndata: {json.dumps(shown)}\n\n"
                    last = shown
                if job.state.final:
                    return
                await asyncio.sleep(EVENT_TICK)

        return StreamingResponse(stream(), media_type="text/event-stream")

    async def logs(self, request: Request) -> JSONResponse:
        """A job's log (`service.table.JobTable.lines`) and state, for its owner alone."""
        job_id = request.path_params["id"]
        job = self.table.get(job_id)
        if job is None:
            return _error(404, "no such job")
        if job.owner != request.state.owner:
            return _error(403, f"job {job_id} is {job.owner}'s: only its owner may read its log")
        lines = self.table.lines(job_id)
        return JSONResponse({"id": job_id, "state": job.state.value, "lines": lines})

    async def page_list(self, request: Request) -> HTMLResponse:
        return HTMLResponse(list_page(self.table.list()))

    async def page_job(self, request: Request) -> HTMLResponse:
        job = self.table.get(request.path_params["id"])
        if job is None:
            return HTMLResponse(page("no such job", "<p>no such job</p>"), status_code=404)
        csrf = csrf_token(self.secret, request.cookies.get(COOKIE, ""))
        return HTMLResponse(job_page(job, viewer=request.state.owner, csrf=csrf))

    async def picture(self, request: Request) -> Response:
        job_id, kind = request.path_params["id"], request.path_params["picture"]
        job = self.table.get(job_id)
        if job is None or job.state is not JobState.SUCCEEDED or kind not in KINDS:
            return _error(404, "no such picture")
        try:
            picture = await self.pictures.get(job, kind)
        except InputError as error:  # e.g. nothing swept: nothing to plot against
            return _error(404, str(error))
        return Response(picture, media_type="image/png")


def _refused(status: int, reason: str) -> HTMLResponse:
    """A page's refusal, as a page."""
    return HTMLResponse(page("refused", f"<p>{html.escape(reason)}</p>"), status_code=status)


def create_app(runner: Runner, tokens: dict[str, str]):
    """The ASGI application over a started `runner`; no token: no authentication.

    Without tokens it answers a loopback ``Host`` alone (`service.guards.loopback_only`).
    """
    app = Starlette(routes=_Service(runner, tokens).routes())
    return secured(app if tokens else loopback_only(app))


def serve(args, security) -> int:
    """Run the service until interrupted (the ``serve`` command); `security` as for run."""
    tokens = read_tokens(args.token_file)
    if args.no_auth:
        if args.host not in LOOPBACK:
            raise BadOptionError(f"--no-auth is allowed on 127.0.0.1 only, not --host {args.host}")
        tokens = {}
    elif not tokens:
        raise BadOptionError(
            "no token: give --token-file PATH or OCEANLIDAR_TOKEN (or --no-auth, on "
            "127.0.0.1 only)"
        )
    for flag in ("max_running", "queue_limit", "batch"):
        if getattr(args, flag) is not None and getattr(args, flag) < 1:
            raise BadOptionError(f"--{flag.replace('_', '-')} must be at least 1")
    backend = choose(args.backend, args.device, here=args.scheduler is None)
    memory = given_memory(args.batch_memory)
    root = Store.at(args.data_root, args.storage_options)
    local = "://" not in root.url
    if local and os.path.exists(root.url) and not os.path.isdir(root.url):
        raise BadOptionError(f"--data-root {args.data_root}: exists and is not a folder")
    with _listening(args.host, args.port) as listener:
        table = JobTable(args.db)  # before the data root is made: every refusal comes first
        if local:
            try:
                os.makedirs(root.url, exist_ok=True)
            except OSError as error:
                raise BadOptionError(
                    f"--data-root {args.data_root}: cannot make the folder ({error.strerror})"
                ) from None
        with dask_client(
            workers=args.workers,
            scheduler=args.scheduler,
            security=security,
            device=backend.device,
        ) as client:
            runner = Runner(
                table,
                client,
                data_root=root,
                max_running=args.max_running,
                queue_limit=args.queue_limit,
                batch_size=args.batch,
                backend=backend,
                batch_memory=memory,
            )
            limit = connection_limit()
            config = uvicorn.Config(
                create_app(runner, tokens),
                log_level="warning",
                access_log=False,
                http=functools.partial(Connection, limit=limit),
                backlog=limit,  # also the most connections accepted in one go
            )
            runner.start()
            print(
                f"oceanlidar serve: http://{args.host}:{args.port} (data root {root.url}, "
                f"jobs {args.db})",
                file=sys.stderr,
                flush=True,
            )
            try:
                Server(config).run(sockets=[listener])
            finally:
                runner.stop()
    return 0


def _listening(host: str, port: int) -> socket.socket:
    """A socket listening on `host`:`port`, bound before anything else starts.

    Raises
    ------
    BadOptionError
        If the address cannot be bound (the port in use, a host not of this machine).
    """
    try:
        return socket.create_server(
            (host, port), family=socket.AF_INET6 if ":" in host else socket.AF_INET
        )
    except OSError as error:
        raise BadOptionError(
            f"--host {host} --port {port}: cannot listen there ({error.strerror or error})"
        ) from None
