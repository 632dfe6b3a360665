"""What the job service checks of every request before a route, and who may send them.

`secured` adds `SECURITY_HEADERS` to every answer; `loopback_only` answers a service
without tokens only at a loopback ``Host`` (DNS rebinding); `read_tokens` reads who may
call it.
"""

from __future__ import annotations

import os
import urllib.parse

from starlette.responses import JSONResponse

from service.errors import BadFileError

LOOPBACK = ("127.0.0.1", "localhost", "::1")
"""The ``Host`` names a service without tokens answers (`loopback_only`)."""
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


def secured(app):
    """`app` (ASGI) with `SECURITY_HEADERS` added to every HTTP answer."""

    async def secured(scope, receive, send):
        async def send_secured(message):
            if message["type"] == "http.response.start":
                message = {**message, "headers": [*message["headers"], *SECURITY_HEADERS]}
            await send(message)

        await app(scope, receive, send_secured if scope["type"] == "http" else send)

    return secured


def loopback_only(app):
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
                refusal = JSONResponse(
                    {
                        "error": f"Host {host!r}: this service answers its loopback address "
                        "only (127.0.0.1, localhost, ::1)"
                    },
                    status_code=403,
                )
                return await refusal(scope, receive, send)
        await app(scope, receive, send)

    return checked
