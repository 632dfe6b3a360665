"""Headless Chromium for the tests, driven through the DevTools protocol on a pipe.

``--remote-debugging-pipe``: the browser reads commands from its descriptor 3 and writes
answers to its descriptor 4, JSON messages ended by a NUL byte. No port is opened and no
package is needed beyond the ``chromium`` binary (Debian's ``chromium``, which ``.ci/run``
installs); without it the tests that need a browser skip, except where
``OCEANLIDAR_REQUIRE_BROWSER=1`` (CI) makes them fail.
"""

import contextlib
import json
import os
import select
import shutil
import subprocess
import time

import pytest

__all__ = ["Browser", "chromium_binary"]

FLAGS = (
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--no-first-run",
)
"""Chromium's flags for a quiet headless browser that reaches nothing but the pages asked."""


def chromium_binary() -> str:
    """The Chromium binary; the test skips where there is none (fails under CI's
    ``OCEANLIDAR_REQUIRE_BROWSER=1``: ``.ci/run`` installs it)."""
    binary = shutil.which("chromium") or shutil.which("chromium-browser")
    if binary is None:
        missing = "no chromium binary (apt-get install chromium); the page is not tested"
        if os.environ.get("OCEANLIDAR_REQUIRE_BROWSER") == "1":
            pytest.fail(missing)
        pytest.skip(missing)
    return binary


class Browser:
    """One headless Chromium with one page (tab), driven by DevTools protocol commands.

    Parameters
    ----------
    folder : Path
        Where its profile and its log (``chromium.log``) go.
    timeout : float, optional
        Seconds any one command or wait may take [s].
    """

    def __init__(self, folder, *, timeout: float = 60.0):
        self.timeout = timeout
        commands, self._to = os.pipe()
        self._from, answers = os.pipe()
        self.log = open(folder / "chromium.log", "wb")
        shell = f'exec "$0" "$@" 3<&{commands} 4>&{answers}'
        self.process = subprocess.Popen(
            [
                "bash",  # dash takes descriptors 0 to 9 alone
                "-c",
                shell,
                chromium_binary(),
                *FLAGS,
                f"--user-data-dir={folder / 'profile'}",
                "--remote-debugging-pipe",
                "about:blank",
            ],
            pass_fds=(commands, answers),
            stdin=subprocess.DEVNULL,
            stdout=self.log,
            stderr=self.log,
            start_new_session=True,
        )
        os.close(commands)
        os.close(answers)
        self._sent = 0
        self._read = b""
        target = self.call("Target.createTarget", url="about:blank")["targetId"]
        self.session = self.call("Target.attachToTarget", targetId=target, flatten=True)[
            "sessionId"
        ]

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def close(self) -> None:
        """End the browser (its whole process group)."""
        with contextlib.suppress(OSError):
            os.close(self._to)
        os.close(self._from)
        with contextlib.suppress(ProcessLookupError):
            os.killpg(self.process.pid, 9)
        self.process.wait(timeout=30)
        self.log.close()

    def call(self, method: str, *, session: str | None = None, **params) -> dict:
        """The result of the protocol command `method` (on the page if `session`)."""
        self._sent += 1
        message = {"id": self._sent, "method": method, "params": params}
        if session is not None:
            message["sessionId"] = session
        os.write(self._to, json.dumps(message).encode() + b"\0")
        deadline = time.monotonic() + self.timeout
        while True:
            answer = self._message(deadline)
            if answer.get("id") == self._sent:  # else an event: not asked for
                if "error" in answer:
                    raise RuntimeError(f"{method}: {answer['error']}")
                return answer["result"]

    def _message(self, deadline: float) -> dict:
        while b"\0" not in self._read:
            left = deadline - time.monotonic()
            if left <= 0 or not select.select([self._from], [], [], left)[0]:
                raise TimeoutError("the browser did not answer")
            chunk = os.read(self._from, 1 << 16)
            if not chunk:
                raise RuntimeError("the browser ended (see chromium.log)")
            self._read += chunk
        message, _, self._read = self._read.partition(b"\0")
        return json.loads(message)

    def evaluate(self, expression: str):
        """The value of the JavaScript `expression` in the page."""
        result = self.call(
            "Runtime.evaluate",
            session=self.session,
            expression=expression,
            returnByValue=True,
            awaitPromise=True,
        )
        if "exceptionDetails" in result:
            raise RuntimeError(f"{expression}: {result['exceptionDetails']}")
        return result["result"].get("value")

    def go(self, url: str) -> None:
        """Load `url` in the page and wait until it has loaded."""
        self.call("Page.navigate", session=self.session, url=url)
        self.wait(f"location.href === {json.dumps(url)} && document.readyState === 'complete'")

    def wait(self, expression: str):
        """The first truthy value of `expression`, looked at every 0.1 s (a page may be
        loading meanwhile: its errors are looked past until the time is up)."""
        deadline = time.monotonic() + self.timeout
        while time.monotonic() < deadline:
            with contextlib.suppress(RuntimeError):
                if value := self.evaluate(expression):
                    return value
            time.sleep(0.1)
        raise TimeoutError(f"never true in the page: {expression}")

    def click(self, selector: str) -> None:
        """Click the middle of the element `selector` with the mouse, as a user does."""
        x, y = self.wait(
            f"(() => {{ const element = document.querySelector({json.dumps(selector)});"
            " if (!element) return null; const box = element.getBoundingClientRect();"
            " return [box.x + box.width / 2, box.y + box.height / 2]; })()"
        )
        for kind in ("mousePressed", "mouseReleased"):
            self.call(
                "Input.dispatchMouseEvent",
                session=self.session,
                type=kind,
                x=x,
                y=y,
                button="left",
                clickCount=1,
            )
