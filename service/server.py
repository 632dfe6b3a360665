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
origin. Every answer forbids framing, sniffing and anything
the pages do not load from the service itself (`SECURITY_HEADERS`). No request that changes
something is taken from another site's page: a foreign ``Origin`` is refused, and a
submission must carry a type no page may post unasked (`SWEEP_TYPES`); a service without
tokens answers a loopback ``Host`` alone (`_loopback_only`: DNS rebinding). Connections are
bounded in number and in the time they take to send their headers (`_Connection`). A
service whose job table was lost (the file deleted, replaced, overwritten or truncated
while it serves) answers ``503`` everywhere, health included.
"""

from __future__ import annotations

import asyncio
import functools
import hmac
import html
import json
import os
import resource
import secrets
import socket
import sys
import time
import urllib.parse

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
from uvicorn.protocols.http.h11_impl import H11Protocol

from service import package_version
from service.cluster import dask_client
from service.devices import choose
from service.errors import BadFileError, BadOptionError, InputError
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

__all__ = ["LOOPBACK", "create_app", "read_tokens", "serve"]

LOOPBACK = ("127.0.0.1", "localhost", "::1")
COOKIE = "oceanlidar_token"
EVENT_TICK = 0.5
"""Seconds between looks at a job for its event stream."""
SAFE_METHODS = ("GET", "HEAD")
"""Requests the login cookie may authenticate: they read, never change anything."""
SECURITY_HEADERS = [
    (
        b"content-security-policy",
        b"default-src 'none'; img-src 'self'; style-src 'unsafe-inline'; "
        b"script-src 'self'; connect-src 'self'; form-action 'self'; "
        b"frame-ancestors 'none'; base-uri 'none'",
    ),
    (b"x-frame-options", b"DENY"),
    (b"x-content-type-options", b"nosniff"),
    (b"referrer-policy", b"same-origin"),
]
"""Sent with every answer: the pages load nothing but their own pictures, script and event
streams, in no frame. ``same-origin``: another site learns no page address of the service,
while the service's own forms keep their ``Origin`` (under ``no-referrer`` browsers send
``Origin: null`` with every form, and the cancel button was refused)."""
SWEEP_TYPES = (
    "application/yaml",
    "application/x-yaml",
    "text/yaml",
    "text/x-yaml",
    "application/json",
)
"""The ``Content-Type``s a submission may carry: none is one a page of another site may send
without the browser asking the service first (a CORS preflight, which it does not answer)."""


HEADER_TIMEOUT = 10.0
"""Seconds a connection has to send a request's headers (from its start, or from the end of
the previous answer): then it is closed (`_Connection`)."""
LOG_EVERY = 60.0
"""Seconds between two log lines of one kind of event-loop error (`_QuietErrors`)."""


def connection_limit() -> int:
    """The most connections the service holds open (`_Connection`).

    An eighth of the process's descriptors (``RLIMIT_NOFILE``), at least 16 and at most
    1024; as many again may be accepted at once, a few times before the surplus is closed
    (the listening socket's backlog, `serve`): the rest are its jobs' and its cluster's.
    """
    soft, _ = resource.getrlimit(resource.RLIMIT_NOFILE)
    return max(16, min(1024, (soft if soft != resource.RLIM_INFINITY else 8192) // 8))


class _Connection(H11Protocol):
    """uvicorn's HTTP/1.1 connection, bounded in time and number.

    A connection that has not sent a whole request's headers `HEADER_TIMEOUT` seconds after
    it opened (or after its previous answer) is closed: uvicorn waits for headers without
    end. Past `limit` connections, the oldest of those waiting for headers is closed for the
    new one (a client that sends its request at once is served; one that holds connections
    open without sending loses them first); if none waits, the new one is answered ``503``.
    uvicorn's own ``limit_concurrency`` counts connections but refuses only requests whose
    headers came, so half-sent ones still held a descriptor each until the process had none.
    """

    def __init__(self, *args, limit: int, **options):
        super().__init__(*args, **options)
        self.limit = limit
        self.waiting_since = time.monotonic()
        self.deadline: asyncio.TimerHandle | None = None

    def waiting(self) -> bool:
        """Whether it waits for a request's headers (none is being answered), still open."""
        waits = self.cycle is None or self.cycle.response_complete
        return waits and not self.transport.is_closing()

    def connection_made(self, transport) -> None:
        super().connection_made(transport)
        if len(self.connections) > self.limit:
            idle = [c for c in self.connections if c is not self and c.waiting()]
            if not idle:
                transport.write(BUSY)
                transport.close()
                return
            min(idle, key=lambda connection: connection.waiting_since).transport.close()
        self._wait()

    def _wait(self) -> None:
        self.waiting_since = time.monotonic()
        if self.deadline is not None:
            self.deadline.cancel()
        self.deadline = self.loop.call_later(HEADER_TIMEOUT, self._expired)

    def _expired(self) -> None:
        if self.waiting():
            self.transport.close()

    def on_response_complete(self) -> None:
        super().on_response_complete()
        if not self.transport.is_closing():
            self._wait()

    def connection_lost(self, exc) -> None:
        if self.deadline is not None:
            self.deadline.cancel()
        super().connection_lost(exc)


_BUSY = b'{"error": "the service holds too many connections: retry"}'
BUSY = (
    b"HTTP/1.1 503 Service Unavailable\r\ncontent-type: application/json\r\n"
    b"connection: close\r\ncontent-length: %d\r\n\r\n%s" % (len(_BUSY), _BUSY)
)
"""The answer to a connection past the limit when every other one is being answered."""


class _QuietErrors:
    """An event loop's exception handler that logs each kind of error once a `LOG_EVERY`.

    A process out of descriptors fails every ``accept`` (``EMFILE``) and logs a traceback
    each time: tens of megabytes a minute. The first of a kind (by message) is logged,
    then one a `LOG_EVERY` seconds with the count of those not logged.
    """

    def __init__(self):
        self.logged: dict[str, float] = {}
        self.unlogged: dict[str, int] = {}

    def __call__(self, loop, context: dict) -> None:
        kind = str(context.get("message"))
        now = time.monotonic()
        if now - self.logged.get(kind, -LOG_EVERY) < LOG_EVERY:
            self.unlogged[kind] = self.unlogged.get(kind, 0) + 1
            return
        if unlogged := self.unlogged.pop(kind, 0):
            context = {**context, "message": f"{kind} (and {unlogged} more since the last)"}
        self.logged[kind] = now
        loop.default_exception_handler(context)


class _Server(uvicorn.Server):
    """uvicorn's server with `_QuietErrors` on its event loop."""

    async def startup(self, sockets=None) -> None:
        asyncio.get_running_loop().set_exception_handler(_QuietErrors())
        await super().startup(sockets=sockets)


def read_tokens(path: str | None) -> dict[str, str]:
    """Tokens by owner: the lines ``OWNER TOKEN`` (or ``TOKEN`` alone) of `path`.

    Without `path`, the ``OCEANLIDAR_TOKEN`` environment variable, owner ``default``.

    Raises
    ------
    BadFileError
        If the file cannot be read, or names an owner or a token twice (a token must say
        who sent it).
    """
    if path is None:
        token = os.environ.get("OCEANLIDAR_TOKEN", "").strip()
        return {"default": token} if token else {}
    try:
        with open(path, encoding="utf-8") as handle:
            lines = [line.split() for line in handle if line.strip() and line[0] != "#"]
    except (OSError, UnicodeDecodeError) as error:
        raise BadFileError(f"--token-file {path}: {getattr(error, 'strerror', error)}") from None
    if any(len(fields) > 2 for fields in lines):
        raise BadFileError(f"--token-file {path}: one 'OWNER TOKEN' or 'TOKEN' a line")
    owners = [fields[0] if len(fields) == 2 else "default" for fields in lines]
    tokens = [fields[-1] for fields in lines]
    for kind, names in (("owner", owners), ("token", tokens)):
        if len(set(names)) < len(names):
            raise BadFileError(f"--token-file {path}: each {kind} may appear on one line only")
    return dict(zip(owners, tokens, strict=True))


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


def _secured(app):
    """`app` (ASGI) with `SECURITY_HEADERS` added to every HTTP answer."""

    async def secured(scope, receive, send):
        async def send_secured(message):
            if message["type"] == "http.response.start":
                message = {**message, "headers": [*message["headers"], *SECURITY_HEADERS]}
            await send(message)

        await app(scope, receive, send_secured if scope["type"] == "http" else send)

    return secured


def _loopback_only(app):
    """`app` (ASGI) answering only requests whose ``Host`` names a loopback address.

    For a service without tokens (``--no-auth``, on loopback only): a page of another site
    that makes its own name resolve to 127.0.0.1 (DNS rebinding) has its requests sent with
    its own name as ``Host``, and is refused (``403``); the port is not looked at (an SSH
    tunnel's port differs).
    """

    async def checked(scope, receive, send):
        if scope["type"] == "http":
            host = dict(scope["headers"]).get(b"host", b"").decode("latin-1")
            try:
                name = urllib.parse.urlsplit(f"//{host}").hostname
            except ValueError:  # a port that is not a number
                name = None
            if name not in LOOPBACK:
                refusal = _error(
                    403,
                    f"Host {host!r}: this service answers its loopback address only "
                    "(127.0.0.1, localhost, ::1)",
                )
                return await refusal(scope, receive, send)
        await app(scope, receive, send)

    return checked


def create_app(runner: Runner, tokens: dict[str, str]):
    """The ASGI application over a started `runner`; no token: no authentication.

    Without tokens it answers requests to a loopback ``Host`` alone (`_loopback_only`).
    """
    app = Starlette(routes=_Service(runner, tokens).routes())
    return _secured(app if tokens else _loopback_only(app))


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
            )
            limit = connection_limit()
            config = uvicorn.Config(
                create_app(runner, tokens),
                log_level="warning",
                access_log=False,
                http=functools.partial(_Connection, limit=limit),
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
                _Server(config).run(sockets=[listener])
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
