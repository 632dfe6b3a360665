"""The job service's connections, bounded in number and in the time they take to send headers.

`Connection` is uvicorn's HTTP/1.1 protocol with a header-read deadline and a cap on open
connections (`connection_limit`); `Server` is uvicorn's server whose event loop logs each
kind of error once a minute (`QuietErrors`): a flood of half-sent requests exhausts no
descriptor and fills no log (issue #37 item 9).
"""

from __future__ import annotations

import asyncio
import resource
import time

import uvicorn
from uvicorn.protocols.http.h11_impl import H11Protocol

HEADER_TIMEOUT = 10.0
"""Seconds a connection has to send a request's headers (from its start, or from the end of
the previous answer): then it is closed (`Connection`)."""
LOG_EVERY = 60.0
"""Seconds between two log lines of one kind of event-loop error (`QuietErrors`)."""


def connection_limit() -> int:
    """The most connections the service holds open (`Connection`).

    An eighth of the process's descriptors (``RLIMIT_NOFILE``), at least 16 and at most
    1024; as many again may be accepted at once, a few times before the surplus is closed
    (the listening socket's backlog, `serve`): the rest are its jobs' and its cluster's.
    """
    soft, _ = resource.getrlimit(resource.RLIMIT_NOFILE)
    return max(16, min(1024, (soft if soft != resource.RLIM_INFINITY else 8192) // 8))


class Connection(H11Protocol):
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
        """Make room past the limit (or answer ``503``), then start the header deadline."""
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
        """Start the next request's header deadline."""
        super().on_response_complete()
        if not self.transport.is_closing():
            self._wait()

    def connection_lost(self, exc) -> None:
        """Drop the header deadline."""
        if self.deadline is not None:
            self.deadline.cancel()
        super().connection_lost(exc)


BUSY_BODY = b'{"error": "the service holds too many connections: retry"}'
BUSY = (
    b"HTTP/1.1 503 Service Unavailable\r\ncontent-type: application/json\r\n"
    b"connection: close\r\ncontent-length: %d\r\n\r\n%s" % (len(BUSY_BODY), BUSY_BODY)
)
"""The answer to a connection past the limit when every other one is being answered."""


class QuietErrors:
    """An event loop's exception handler that logs each kind of error once a `LOG_EVERY`.

    A process out of descriptors fails every ``accept`` (``EMFILE``) and logs a traceback
    each time: tens of megabytes a minute. The first of a kind (by message) is logged,
    then one a `LOG_EVERY` seconds with the count of those not logged.
    """

    def __init__(self):
        self.logged: dict[str, float] = {}
        self.unlogged: dict[str, int] = {}

    def __call__(self, loop, context: dict) -> None:
        """Log `context` unless its kind was logged in the last `LOG_EVERY` seconds."""
        kind = str(context.get("message"))
        now = time.monotonic()
        if now - self.logged.get(kind, -LOG_EVERY) < LOG_EVERY:
            self.unlogged[kind] = self.unlogged.get(kind, 0) + 1
            return
        if unlogged := self.unlogged.pop(kind, 0):
            context = {**context, "message": f"{kind} (and {unlogged} more since the last)"}
        self.logged[kind] = now
        loop.default_exception_handler(context)


class Server(uvicorn.Server):
    """uvicorn's server with `QuietErrors` on its event loop."""

    async def startup(self, sockets=None) -> None:
        """Install `QuietErrors` on the running loop, then start."""
        asyncio.get_running_loop().set_exception_handler(QuietErrors())
        await super().startup(sockets=sockets)
