"""The batch service: a real `oceanlidar serve` process, real HTTP on loopback, real workers."""

import contextlib
import http.client
import json
import os
import re
import resource
import shutil
import signal
import socket
import sqlite3
import subprocess
import tempfile
import threading
import time
import urllib.error
import urllib.parse
import urllib.request

import pytest
from browser import FLAGS, Browser, chromium_binary
from conftest import (
    TINY_SWEEP,
    assert_same_samples,
    cli_command,
    free_port,
    on_cluster,
    store_lock,
)

from service.cli import main
from service.cli.job_commands import _line
from service.connections import HEADER_TIMEOUT
from service.pages import job_page
from service.store.location import KIND, Store
from service.store.template import OWNER

TOKEN = "s3cret-token"
LONG = 40
"""Realisations per point of the sweep the jobs run (two points): long enough to act on."""


def sweep(output, *, realisations=LONG, name="served"):
    return TINY_SWEEP.format(name=name, seed=5, realisations=realisations, output=output)


class Server:
    """An `oceanlidar serve` process in its own process group (its workers with it)."""

    def __init__(self, folder, *args, token=TOKEN, descriptors=None):
        self.folder, self.args, self.token = folder, args, token
        self.descriptors = descriptors  # its RLIMIT_NOFILE, if not this process's
        self.port = free_port()
        self.url = f"http://127.0.0.1:{self.port}"
        self.process = None

    def start(self):
        env = {"OCEANLIDAR_TOKEN": self.token} if self.token else {}
        command, env = cli_command(
            "serve",
            "--port",
            self.port,
            "--db",
            self.folder / "jobs.sqlite",
            "--data-root",
            self.folder / "data",
            *([] if "--scheduler" in self.args else ["--workers", "2"]),
            "--batch",
            "1",
            *self.args,
            env=env,
        )
        self.log = open(self.folder / "server.log", "ab")
        self.process = subprocess.Popen(
            command,
            cwd=self.folder,
            env=env,
            stdout=self.log,
            stderr=self.log,
            start_new_session=True,
            preexec_fn=None if self.descriptors is None else self._limit,
        )
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:
            assert self.process.poll() is None, (self.folder / "server.log").read_text()
            with contextlib.suppress(OSError):
                if self.request("GET", "/v1/health")[0] == 200:
                    return self
            time.sleep(0.2)
        raise AssertionError("the server did not answer within 60 s")

    def _limit(self):
        resource.setrlimit(resource.RLIMIT_NOFILE, (self.descriptors, self.descriptors))

    def request(self, method, path, body=None, *, token=None):
        request = urllib.request.Request(self.url + path, data=body, method=method)
        if body is not None:
            request.add_header("Content-Type", "application/yaml")
        if token or self.token:
            request.add_header("Authorization", f"Bearer {token or self.token}")
        try:
            with urllib.request.urlopen(request, timeout=30) as response:
                return response.status, json.loads(response.read())
        except urllib.error.HTTPError as error:
            return error.code, json.loads(error.read())

    def submit(self, text, mode="new"):
        return self.request("POST", f"/v1/jobs?mode={mode}", text.encode())

    def job(self, job_id):
        return self.request("GET", f"/v1/jobs/{job_id}")[1]

    def wait(self, job_id, until, timeout=120):
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            job = self.job(job_id)
            if until(job):
                return job
            time.sleep(0.05)
        raise AssertionError(f"job {job_id} never got there: {job}")

    def kill(self, sig=signal.SIGKILL):
        """Send `sig` to the server and its workers; wait for the server to end."""
        with contextlib.suppress(ProcessLookupError):
            os.killpg(self.process.pid, sig)
        self.process.wait(timeout=30)

    def stop(self):
        if self.process is not None and self.process.poll() is None:
            self.process.send_signal(signal.SIGTERM)
            try:
                self.process.wait(timeout=30)
            except subprocess.TimeoutExpired:
                pass
        if self.process is not None:
            with contextlib.suppress(ProcessLookupError):  # leftover workers
                os.killpg(self.process.pid, signal.SIGKILL)
            self.process.wait(timeout=30)
            self.log.close()


@contextlib.contextmanager
def running(folder, *args, token=TOKEN):
    server = Server(folder, *args, token=token)
    try:
        yield server.start()
    finally:
        server.stop()


def finished(job):
    return job["state"] in ("succeeded", "failed", "cancelled", "rejected")


@pytest.fixture(scope="module")
def reference(tmp_path_factory, session_cluster):
    """The sweep run by `oceanlidar run`."""
    folder = tmp_path_factory.mktemp("reference")
    (folder / "sweep.yaml").write_text(sweep("reference.zarr"))
    with on_cluster(session_cluster), pytest.MonkeyPatch.context() as patch:
        patch.chdir(folder)
        assert main(["run", "sweep.yaml", "--workers", "1"]) == 0
    return folder / "reference.zarr"


OTHER_TOKEN = "another-token"


@pytest.fixture(scope="module")
def service(tmp_path_factory):
    folder = tmp_path_factory.mktemp("service")
    (folder / "tokens").write_text(f"# owner token\nalice {TOKEN}\nbob {OTHER_TOKEN}\n")
    with running(folder, "--max-running", "2", "--token-file", folder / "tokens") as server:
        yield server


def client(monkeypatch, server, token=TOKEN):
    """The CLI clients talk to `server` (through the environment, as users set it)."""
    monkeypatch.setenv("OCEANLIDAR_SERVER", server.url)
    monkeypatch.setenv("OCEANLIDAR_TOKEN", token)


def test_submit_and_watch_gives_the_bytes_of_run(
    service, reference, tmp_path, monkeypatch, capsys
):
    (tmp_path / "sweep.yaml").write_text(sweep("watched.zarr"))
    client(monkeypatch, service)
    assert main(["submit", str(tmp_path / "sweep.yaml")]) == 0
    job_id = capsys.readouterr().out.strip()
    assert main(["status", job_id, "--watch"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[-1].split()[:3] == [job_id, "succeeded", f"{2 * LONG}/{2 * LONG}"]
    job = service.job(job_id)
    assert job["owner"] == "alice" and job["errors"] == {}
    assert_same_samples(job["url"], reference, names=None)
    assert Store(job["url"]).stats.attributes()[KIND] == "statistics"
    assert main(["jobs", "--state", "succeeded"]) == 0
    assert job_id in capsys.readouterr().out


def test_two_jobs_at_once_share_the_cluster(service, reference):
    ids = [
        service.request("POST", "/v1/jobs", sweep(f"shared-{n}.zarr").encode(), token=token)[1][
            "id"
        ]
        for n, token in enumerate([TOKEN, OTHER_TOKEN])
    ]
    assert [service.job(job_id)["owner"] for job_id in ids] == ["alice", "bob"]
    events = []

    def follow():
        request = urllib.request.Request(f"{service.url}/v1/jobs/{ids[0]}/events")
        request.add_header("Authorization", f"Bearer {TOKEN}")
        with urllib.request.urlopen(request, timeout=120) as stream:
            assert stream.headers["content-type"].startswith("text/event-stream")
            events.extend(json.loads(line[6:]) for line in stream if line.startswith(b"data: "))

    follower = threading.Thread(target=follow)
    follower.start()
    snapshot = []
    while not any(map(finished, snapshot)):
        time.sleep(0.05)
        snapshot = [service.job(job_id) for job_id in ids]
    # when the first job ends the other has had its share of the workers too
    done = [job["samples"]["done"] for job in snapshot]
    assert min(done) >= 2 * LONG // 4, done
    for job_id in ids:
        job = service.wait(job_id, finished)
        assert job["state"] == "succeeded", job
        assert_same_samples(job["url"], reference, names=None)
    follower.join(timeout=120)
    done = [event["samples"]["done"] for event in events]
    assert events[-1]["state"] == "succeeded" and done == sorted(done) and len(set(done)) > 2


def test_cancel_stops_the_job_and_resume_completes_it(service, reference, monkeypatch):
    text = sweep("cancelled.zarr")
    job_id = service.submit(text)[1]["id"]
    service.wait(job_id, lambda job: job["samples"]["done"] >= 4)
    # only its owner cancels a job, or resumes or overwrites the store it wrote
    status, answer = service.request("DELETE", f"/v1/jobs/{job_id}", token=OTHER_TOKEN)
    assert status == 403 and "alice" in answer["error"], answer
    assert service.job(job_id)["state"] == "running"
    status, job = service.request("DELETE", f"/v1/jobs/{job_id}")
    assert status == 200 and job["state"] in ("running", "cancelled"), job
    job = service.wait(job_id, finished)
    assert job["state"] == "cancelled", job
    complete = Store(job["url"]).completed()
    time.sleep(2.0)  # nothing runs on after the cancel
    assert (Store(job["url"]).completed() == complete).all()
    assert 4 <= complete.sum() < 2 * LONG
    assert not store_lock(job["url"]).exists()
    client(monkeypatch, service)
    assert main(["status", job_id]) == 1
    status, refused = service.submit(text)  # an existing output: 409 at once (issue #27)
    assert status == 409 and "already exists; submit with mode resume" in refused["error"]
    # another owner is not told to resume what only its owner may (a trial's find)
    status, refused = service.request("POST", "/v1/jobs", text.encode(), token=OTHER_TOKEN)
    assert status == 409 and refused["error"].endswith("by alice: choose another output"), refused
    for mode in ("resume", "overwrite"):
        status, refused = service.request(
            "POST", f"/v1/jobs?mode={mode}", text.encode(), token=OTHER_TOKEN
        )
        assert status == 403 and refused["error"].startswith("output:"), refused
    status, again = service.submit(text, mode="resume")
    assert status == 201
    assert service.wait(again["id"], finished)["state"] == "succeeded"
    assert_same_samples(job["url"], reference, names=None)
    assert service.request("DELETE", f"/v1/jobs/{again['id']}")[0] == 409


SLOW = """\
name: slow
seed: 3
realisations: 8
output: slow.zarr
scene:
  surface: {grid_size: 2048, spacing: 0.05}  # a large sea: about 0.2 s a sample
  receiver: {pixels: 8, gates: [[2.0, 6.0]]}
"""


def test_cancel_lets_no_task_write_on(service):
    job_id = service.submit(SLOW)[1]["id"]
    service.wait(job_id, lambda job: job["samples"]["done"] >= 1)
    assert service.request("DELETE", f"/v1/jobs/{job_id}")[0] == 200
    job = service.wait(job_id, finished)
    assert job["state"] == "cancelled", job
    complete = Store(job["url"]).completed()
    assert complete.sum() == job["samples"]["done"] < 8
    time.sleep(1.0)  # tasks that were executing ended before the job said cancelled
    assert (Store(job["url"]).completed() == complete).all()


def test_sigkill_mid_job_then_restart_resumes(reference, tmp_path, monkeypatch, capsys):
    server = Server(tmp_path, "--max-running", "1")
    try:
        server.start()
        first = server.submit(sweep("killed.zarr"))[1]["id"]
        second = server.submit(sweep("waiting.zarr", realisations=1))[1]["id"]
        third = server.submit(sweep("dropped.zarr", realisations=1))[1]["id"]
        server.wait(first, lambda job: job["samples"]["done"] >= 6)
        server.kill()
        url = str(tmp_path / "data" / "killed.zarr")
        assert 6 <= Store(url).completed().sum() < 2 * LONG
        # the server comes back as another process on another host (a restarted pod): the
        # lock its job left still names the job, and is taken over
        lock = store_lock(tmp_path / "data" / "killed.zarr")
        holder = json.loads(lock.read_text())
        lock.write_text(json.dumps({**holder, "host": "an-earlier-pod", "pid": 1}))
        # a job killed as it started, before its overwrite had replaced the old store
        replaced = str(tmp_path / "data" / "replaced.zarr")
        shutil.copytree(reference, replaced)
        with sqlite3.connect(tmp_path / "jobs.sqlite") as table:
            table.execute(
                "UPDATE jobs SET state = 'running', mode = 'overwrite', output = ?, url = ? "
                "WHERE id = ?",
                ("replaced.zarr", replaced, second),
            )
        server.start()
        assert server.job(third)["state"] == "queued"
        client(monkeypatch, server)
        assert main(["cancel", third]) == 0
        assert "cancelled" in capsys.readouterr().out
        job = server.wait(first, finished)
        assert job["state"] == "succeeded" and job["resumed"], job
        assert_same_samples(url, reference, names=None)
        assert server.wait(second, finished)["state"] == "succeeded"
        done = Store(replaced).completed()
        assert done.size == 2 and done.all()  # one realisation of two points: replaced
        assert server.job(third)["state"] == "cancelled"
        assert not (tmp_path / "data" / "dropped.zarr").exists()
    finally:
        server.stop()


def test_half_sent_requests_exhaust_no_descriptor_and_fail_no_job(tmp_path):
    """Issue #37 item 9: a client that opens connections and never ends its request's
    headers held a descriptor each until the service had none (``EMFILE``): its health
    check timed out, its running job failed and its log filled with tracebacks."""
    descriptors = 256
    held = descriptors + 100
    server = Server(tmp_path, "--max-running", "1", descriptors=descriptors)
    attackers = []
    try:
        server.start()
        job_id = server.submit(sweep("held.zarr", realisations=2000))[1]["id"]
        server.wait(job_id, lambda job: job["samples"]["done"] >= 1)
        for _ in range(held):
            attacker = socket.create_connection(("127.0.0.1", server.port), timeout=30)
            attacker.sendall(b"GET /v1/health HTTP/1.1\r\nHost: 127.0.0.1\r\n")
            attackers.append(attacker)
        # a client that sends its request at once is answered meanwhile
        assert server.request("GET", "/v1/health")[0] == 200
        # and the half-sent ones are closed, the last within the header deadline
        deadline = time.monotonic() + 4 * HEADER_TIMEOUT
        for attacker in attackers:
            attacker.settimeout(max(0.01, deadline - time.monotonic()))
            with contextlib.suppress(ConnectionResetError):
                while attacker.recv(4096):  # until the service closes it (503s read past)
                    pass
        during = server.job(job_id)
        assert during["state"] == "running" and during["errors"] == {}, during
        server.wait(job_id, lambda job: job["samples"]["done"] > during["samples"]["done"])
        assert server.request("DELETE", f"/v1/jobs/{job_id}")[0] == 200
        job = server.wait(job_id, finished)
        assert job["state"] == "cancelled" and job["errors"] == {}, job
    finally:
        for attacker in attackers:
            attacker.close()
        server.stop()
    log = (tmp_path / "server.log").read_text()
    assert "Traceback" not in log and len(log) < 10_000, log[-3000:]


def test_a_terminated_service_closes_its_cluster_and_exits_0(tmp_path):
    # issue #27: uvicorn raised the SIGTERM it had caught again under the system's default
    # handler, which ended the process before its cluster closed: killed by the signal,
    # the workers' semaphores leaked (the resource tracker's warning)
    server = Server(tmp_path).start()
    try:
        server.process.send_signal(signal.SIGTERM)
        code = server.process.wait(timeout=60)
    finally:
        server.stop()
    log = (tmp_path / "server.log").read_text()
    assert code == 0, log
    assert "leaked semaphore" not in log and "Traceback" not in log, log


def test_no_token_is_401_and_serve_refuses_to_run_open(service, monkeypatch, capsys):
    assert service.request("GET", "/v1/health")[0] == 200
    for method, path, body in [
        ("GET", "/v1/jobs", None),
        ("POST", "/v1/jobs", sweep("nope.zarr").encode()),
    ]:
        request = urllib.request.Request(service.url + path, data=body, method=method)
        with pytest.raises(urllib.error.HTTPError) as error:
            urllib.request.urlopen(request, timeout=30)
        assert error.value.code == 401
        assert service.request(method, path, body, token="wrong")[0] == 401
    assert not (service.folder / "data" / "nope.zarr").exists()
    # browsers: the token from /login, kept in a cookie
    cookies = urllib.request.HTTPCookieProcessor()
    opener = urllib.request.build_opener(cookies)
    with opener.open(f"{service.url}/", timeout=30) as page:
        assert page.url.endswith("/login") and "password" in page.read().decode()
    wrong = urllib.parse.urlencode({"token": "wrong"}).encode()
    with pytest.raises(urllib.error.HTTPError) as error:
        opener.open(f"{service.url}/login", data=wrong, timeout=30)
    assert error.value.code == 401 and not list(cookies.cookiejar)
    connection = http.client.HTTPConnection("127.0.0.1", service.port, timeout=30)
    connection.putrequest("POST", "/login")
    connection.putheader("Content-Length", "many")
    connection.endheaders()
    assert connection.getresponse().status == 400
    connection.close()
    login = urllib.parse.urlencode({"token": TOKEN}).encode()
    with opener.open(f"{service.url}/login", data=login, timeout=30) as page:
        assert page.url == f"{service.url}/" and "oceanlidar jobs" in page.read().decode()
    client(monkeypatch, service, token="")
    assert main(["jobs"]) == 2
    assert "a valid token is needed" in capsys.readouterr().err
    # refused before anything starts: no cluster, no port taken
    assert main(["serve", "--port", str(free_port())]) == 2
    assert "no token" in capsys.readouterr().err
    assert main(["serve", "--no-auth", "--host", "0.0.0.0"]) == 2
    assert "127.0.0.1 only" in capsys.readouterr().err


@pytest.mark.parametrize(
    "setting, message",
    [
        (["--db", "nodir/x.sqlite"], r"--db nodir/x\.sqlite: cannot open the job table"),
        (["--db", "folder"], r"--db folder: cannot open the job table"),
        (["--db", "text.txt"], r"--db text\.txt: not an SQLite job table"),
        (["--data-root", "text.txt"], r"--data-root text\.txt: exists and is not a folder"),
        (["--port", "99999"], r"argument --port: 99999 is not a port \(1 to 65535\)"),
        (["--port", "busy"], r"--host 127\.0\.0\.1 --port \d+: cannot listen there"),
    ],
)
def test_bad_serve_settings_are_refused_before_anything_is_made(cli, tmp_path, setting, message):
    """Each is exit 2 with a message naming its flag; no traceback, no data root, no table."""
    (tmp_path / "folder").mkdir()
    (tmp_path / "text.txt").write_text("not a database\n")
    with contextlib.ExitStack() as stack:
        if setting[1] == "busy":
            taken = stack.enter_context(socket.create_server(("127.0.0.1", 0)))
            setting = ["--port", str(taken.getsockname()[1])]
        settings = {"--db": "jobs.sqlite", "--data-root": "data", "--port": str(free_port())}
        flag, value = setting
        settings[flag] = value
        result = cli(
            "serve",
            *[x for pair in settings.items() for x in pair],
            cwd=tmp_path,
            env={"OCEANLIDAR_TOKEN": TOKEN},
        )
    assert result.returncode == 2, result.stderr
    assert re.search(message, result.stderr) and "Traceback" not in result.stderr
    assert "oceanlidar serve: http" not in result.stderr
    made = {path.name for path in tmp_path.iterdir()}
    assert made == {"folder", "text.txt"}, made
    assert (tmp_path / "text.txt").read_text() == "not a database\n"


def test_the_cookie_only_reads_and_pages_are_not_framed(service):
    """A page of another site (another port of this host) cannot submit with the cookie."""
    before = len(service.request("GET", "/v1/jobs")[1]["jobs"])
    cookie = {"Cookie": f"oceanlidar_token={TOKEN}", "Content-Type": "application/yaml"}
    foreign = {"Origin": f"http://127.0.0.1:{free_port()}"}
    connection = http.client.HTTPConnection("127.0.0.1", service.port, timeout=30)
    for method, path, body in [
        ("POST", "/v1/jobs?mode=overwrite", sweep("forged.zarr", realisations=1)),
        ("DELETE", "/v1/jobs/0123456789ab", None),
    ]:
        for headers, refused in [(cookie, 401), ({**cookie, **foreign}, 403)]:
            connection.request(method, path, body=body, headers=headers)
            answer = connection.getresponse()
            assert answer.status == refused, (method, headers, answer.read())
            answer.read()
    assert len(service.request("GET", "/v1/jobs")[1]["jobs"]) == before
    for path in ("/", "/v1/jobs"):  # the cookie reads pages and the API
        connection.request("GET", path, headers={"Cookie": f"oceanlidar_token={TOKEN}"})
        answer = connection.getresponse()
        answer.read()
        assert answer.status == 200, path
        assert answer.headers["x-frame-options"] == "DENY"
        assert answer.headers["x-content-type-options"] == "nosniff"
        assert "frame-ancestors 'none'" in answer.headers["content-security-policy"]
    connection.close()


def page_request(server, method, path, *, token=None, body=None, headers=()):
    """(status, headers, text) of a browser's request with the login cookie of `token`."""
    sent = {"Cookie": f"oceanlidar_token={token}"} if token else {}
    if body is not None:
        sent["Content-Type"] = "application/x-www-form-urlencoded"
        body = urllib.parse.urlencode(body)
    connection = http.client.HTTPConnection("127.0.0.1", server.port, timeout=30)
    try:
        connection.request(method, path, body=body, headers={**sent, **dict(headers)})
        answer = connection.getresponse()
        return answer.status, answer.headers, answer.read().decode()
    finally:
        connection.close()


def test_the_job_page_follows_its_events_and_its_owner_cancels_it(service):
    """Issue #27 item 8: no reload every 3 s; rate, times, a cancel button safe from CSRF."""
    job_id = service.submit(sweep("paged-cancel.zarr"))[1]["id"]
    service.wait(job_id, lambda job: job["state"] == "running")
    path = f"/jobs/{job_id}"
    status, headers, text = page_request(service, "GET", path, token=TOKEN)
    assert status == 200 and 'http-equiv="refresh"' not in text
    for fact in ("rate", "time left", "started", "elapsed", "data-field='elapsed'"):
        assert fact in text, fact
    assert '<script src="/job.js" defer></script>' in text
    assert f"<form class='cancel' method='post' action='{path}/cancel'>" in text
    csrf = re.search(r"name='csrf' value='([0-9a-f]{64})'", text).group(1)
    assert "script-src 'self'" in headers["content-security-policy"]
    assert headers["x-frame-options"] == "DENY"
    status, headers, script = page_request(service, "GET", "/job.js")
    assert status == 200 and headers["content-type"].startswith("text/javascript")
    assert "new EventSource(`/v1/jobs/${page.dataset.job}/events`)" in script
    # another owner sees no cancel button, and cannot cancel with their own form's token
    status, _, other = page_request(service, "GET", path, token=OTHER_TOKEN)
    assert status == 200 and "cancel the job" not in other
    bob = re.search(r"name='csrf' value='([0-9a-f]{64})'", other)
    assert bob is None
    cross = {"Origin": f"http://127.0.0.1:{free_port()}"}
    own = {"Origin": service.url}
    forged = [
        (TOKEN, {"csrf": csrf}, cross, 403),  # another site's page: refused by origin
        (TOKEN, {"csrf": csrf}, {"Sec-Fetch-Site": "cross-site"}, 403),
        # a sandboxed frame of any site posts with Origin: null
        (TOKEN, {"csrf": csrf}, {"Origin": "null"}, 403),
        (TOKEN, {"csrf": csrf}, {"Origin": "null", "Sec-Fetch-Site": "cross-site"}, 403),
        (TOKEN, {"csrf": csrf}, {"Referer": "http://evil.example/"}, 403),  # names no origin
        (TOKEN, {}, own, 403),  # no form token: the cookie alone is not enough
        (TOKEN, {"csrf": "0" * 64}, own, 403),
        (OTHER_TOKEN, {"csrf": csrf}, own, 403),  # alice's token is not bob's
        (None, {"csrf": csrf}, own, 303),  # no cookie: to the login page
    ]
    for token, form, headers, expected in forged:
        status, answer, _ = page_request(
            service, "POST", f"{path}/cancel", token=token, body=form, headers=headers
        )
        assert status == expected, (token, form, headers)
        assert answer["x-frame-options"] == "DENY"
    assert service.job(job_id)["state"] == "running"
    status, answer, _ = page_request(
        service, "POST", f"{path}/cancel", token=TOKEN, body={"csrf": csrf}, headers=own
    )
    assert status == 303 and answer["location"] == path
    assert service.wait(job_id, finished)["state"] == "cancelled"
    status, _, text = page_request(service, "GET", path, token=TOKEN)
    assert "cancel the job" not in text and "<script" not in text  # finished: nothing live
    status, _, refused = page_request(
        service,
        "POST",
        "/jobs/0123456789ab/cancel",
        token=TOKEN,
        body={"csrf": csrf},
        headers=own,
    )
    assert status == 404 and "no such job" in refused


BAD_SWEEPS = {
    "not yaml": ("name: [unclosed", None),
    "no seed": ("name: x\noutput: x.zarr\n", "seed"),
    "bad value": (sweep("x.zarr").replace("pixels: 16", "pixels: -3"), "scene.receiver.pixels"),
    # issue #37 item 14: a ZeroDivisionError in the memory estimate was a 500
    "no field of view": (
        sweep("x.zarr").replace("pixels: 16", "pixels: 16, field_of_view_deg: 0"),
        "scene.receiver.field_of_view_deg",
    ),
    "no batches": (
        sweep("x.zarr").replace(
            "scene:\n", "scene:\n  transport: {method: monte_carlo, batches: 0}\n"
        ),
        "scene.transport.batches",
    ),
    "unknown parameter": (
        sweep("x.zarr").replace("target.shape", "target.colour"),
        "sweep.parameters.target.colour",
    ),
    "measurement outside": (
        sweep("x.zarr").replace("surface: {", "surface: {conditioning: {file: ../secret.csv}, "),
        "scene.surface.conditioning.file",
    ),
}
"""Sweeps the CLI refuses too: the same message comes back, by field path."""

ESCAPES = [
    "/tmp/escape.zarr",
    "../escape.zarr",
    "s3://bucket/escape.zarr",
    "link/escape.zarr",
    "simplecache::escape.zarr",
]
"""Outputs that leave the data root (``link`` leads out of it)."""


def test_bad_sweeps_are_400_with_the_cli_message_and_nothing_written(service, tmp_path, capsys):
    data = service.folder / "data"
    before_files = sorted(p.name for p in data.iterdir())
    before_jobs = len(service.request("GET", "/v1/jobs")[1]["jobs"])
    for label, (text, field) in BAD_SWEEPS.items():
        status, answer = service.submit(text)
        assert status == 400, label
        (tmp_path / "bad.yaml").write_text(text)
        assert main(["validate", str(tmp_path / "bad.yaml")]) == 2
        assert answer["error"] in capsys.readouterr().err, label
        assert field is None or answer["error"].startswith(field), (label, answer)
    # the size limits (checked in the background: the job is rejected) name what a
    # submitter can do, not the CLI's --no-limits
    status, answer = service.submit(sweep("big.zarr", realisations=600_000))  # 2 points
    assert status == 201, answer
    message = service.wait(answer["id"], finished)["message"]
    assert "split it into smaller sweeps" in message and "--no-limits" not in message
    # and so does the memory limit, not the CLI's --max-memory
    heavy = sweep("heavy.zarr").replace("pixels: 16", "pixels: 2048")
    status, answer = service.submit(heavy.replace("scene:\n", "scene:\n  sequence: {frames: 4}\n"))
    assert status == 400 and "make each sample smaller" in answer["error"], answer
    assert "--max-memory" not in answer["error"] and "--no-limits" not in answer["error"]
    outside = tempfile.mkdtemp()
    try:
        os.symlink(outside, data / "link")
        for output in ESCAPES:
            status, answer = service.submit(sweep(output))
            assert status == 400 and answer["error"].startswith("output:"), (output, answer)
        assert os.listdir(outside) == []
    finally:
        os.unlink(data / "link")
        shutil.rmtree(outside)
    assert not os.path.exists("/tmp/escape.zarr")
    assert sorted(p.name for p in data.iterdir()) == before_files
    assert len(service.request("GET", "/v1/jobs")[1]["jobs"]) == before_jobs + 1  # big.zarr


def test_a_measurement_file_that_is_a_folder_is_400_and_leaks_nothing(service):
    """``conditioning.file`` naming a folder of the data root: 400 naming the field, and
    the server's open descriptors do not grow with such requests (each one leaked one)."""
    (service.folder / "data" / "measured").mkdir(exist_ok=True)
    text = sweep("folder.zarr").replace("surface: {", "surface: {conditioning: {file: measured}, ")
    descriptors = f"/proc/{service.process.pid}/fd"
    answers = [service.submit(text)]  # the first request's one-off allocations
    before = len(os.listdir(descriptors))
    answers += [service.submit(text) for _ in range(10)]
    after = len(os.listdir(descriptors))
    for status, answer in answers:
        assert status == 400, answer
        assert answer["error"].startswith("scene.surface.conditioning.file"), answer
        assert "not a regular file" in answer["error"], answer
    assert after < before + 5, (before, after)
    assert not (service.folder / "data" / "folder.zarr").exists()


def test_jobs_of_an_unknown_state_are_400(service):
    status, answer = service.request("GET", "/v1/jobs?state=bogus")
    assert status == 400 and answer["error"].startswith(
        "state 'bogus': not one of validating, queued"
    ), answer
    assert service.request("GET", "/v1/jobs?state=queued")[0] == 200


@pytest.fixture(scope="module")
def open_service(tmp_path_factory):
    folder = tmp_path_factory.mktemp("open")
    with running(folder, "--no-auth", "--queue-limit", "1", "--max-running", "1", token="") as s:
        yield s


def test_queue_limit_is_429(open_service):
    status, job = open_service.submit(sweep("first.zarr"))
    assert status == 201 and job["state"] == "validating" and job["owner"] == "anonymous"
    status, answer = open_service.submit(sweep("second.zarr"))
    assert status == 429, answer
    assert [j["id"] for j in open_service.request("GET", "/v1/jobs")[1]["jobs"]] == [job["id"]]
    assert open_service.wait(job["id"], finished)["state"] == "succeeded"
    status, job = open_service.submit(sweep("second.zarr", realisations=1))
    assert status == 201
    assert open_service.wait(job["id"], finished)["state"] == "succeeded"


def test_a_server_without_tokens_refuses_other_sites_and_other_hosts(open_service, tmp_path):
    """Issue #37 item 8: no cross-site or DNS-rebinding write reaches a ``--no-auth`` server.

    A page another site serves may post a ``text/plain`` body without asking the service
    (no CORS preflight); one whose name resolves to 127.0.0.1 (rebinding) sends its own
    name as ``Host``.
    """
    before = open_service.request("GET", "/v1/jobs")[1]["jobs"]
    port = open_service.port
    text = sweep("first.zarr", realisations=1)
    yaml = {"Content-Type": "application/yaml"}
    refusals = [
        ("POST", "/v1/jobs?mode=overwrite", {"Content-Type": "text/plain"}, 415),
        ("POST", "/v1/jobs?mode=overwrite", {}, 415),
        ("POST", "/v1/jobs", {"Content-Type": "application/x-www-form-urlencoded"}, 415),
        ("POST", "/v1/jobs", {"Content-Type": "multipart/form-data; boundary=x"}, 415),
        ("POST", "/v1/jobs?mode=overwrite", {**yaml, "Origin": "http://evil.example"}, 403),
        ("POST", "/v1/jobs", {**yaml, "Origin": f"http://127.0.0.1:{free_port()}"}, 403),
        ("POST", "/v1/jobs", {**yaml, "Origin": "null"}, 403),
        ("POST", "/v1/jobs", {**yaml, "Sec-Fetch-Site": "cross-site"}, 403),
        ("POST", "/v1/jobs", {**yaml, "Host": f"evil.example:{port}"}, 403),
        ("POST", "/v1/jobs", {**yaml, "Host": f"127.0.0.1.evil.example:{port}"}, 403),
        ("DELETE", "/v1/jobs/0123456789ab", {"Origin": "http://evil.example"}, 403),
        ("DELETE", "/v1/jobs/0123456789ab", {"Host": "evil.example"}, 403),
        ("GET", "/v1/jobs", {"Host": f"evil.example:{port}"}, 403),  # nor reads it
        ("GET", "/", {"Host": "evil.example"}, 403),
    ]
    connection = http.client.HTTPConnection("127.0.0.1", port, timeout=30)
    for method, path, headers, status in refusals:
        body = text if method == "POST" else None
        connection.request(method, path, body=body, headers=headers)
        answer = connection.getresponse()
        assert answer.status == status, (method, path, headers, answer.read())
        assert json.loads(answer.read())["error"], headers
    connection.close()
    assert open_service.request("GET", "/v1/jobs")[1]["jobs"] == before
    # the service's own names pass, whatever the port (an SSH tunnel's)
    for host in (f"localhost:{port}", f"127.0.0.1:{port}", "localhost:9999"):
        status, _, _ = page_request(open_service, "GET", "/", headers={"Host": host})
        assert status == 200, host


def test_the_cancel_button_works_in_a_browser(service, tmp_path):
    """Issue #37 item 12: log in, open a running job's page, click cancel, read the page.

    Under ``Referrer-Policy: no-referrer`` Chromium posted the form with ``Origin: null``,
    which the service refused (403) for every click.
    """
    job_id = service.submit(sweep("clicked.zarr", realisations=1000))[1]["id"]
    service.wait(job_id, lambda job: job["state"] == "running")
    with Browser(tmp_path) as browser:
        browser.go(f"{service.url}/login")
        browser.evaluate(f"document.querySelector('input[name=token]').value = '{TOKEN}'")
        browser.click("form button")
        browser.wait("document.title === 'oceanlidar jobs'")
        assert job_id in browser.evaluate("document.body.innerText")
        browser.go(f"{service.url}/jobs/{job_id}")
        assert browser.evaluate("document.querySelector('[data-field=state]').textContent") == (
            "running"
        )
        browser.click("form[action$='/cancel'] button")
        shown = browser.wait(
            "document.title === 'refused' ? document.body.innerText : "
            "document.querySelector('[data-field=state]')?.textContent === 'cancelled' && "
            "location.pathname"
        )
        assert shown == f"/jobs/{job_id}", shown
        assert "cancel the job" not in browser.evaluate("document.body.innerText")
        message = browser.evaluate("document.querySelector('.message').textContent")
    assert message.startswith("cancelled; submit it again with resume"), message
    assert service.job(job_id)["state"] == "cancelled"


def chromium(*args, folder):
    command = [chromium_binary(), *FLAGS, f"--user-data-dir={folder / 'profile'}", *args]
    result = subprocess.run(command, capture_output=True, text=True, timeout=120, cwd=folder)
    assert result.returncode == 0, result.stderr
    return result.stdout


def test_page_shows_the_job_in_a_browser(open_service, tmp_path):
    status, job = open_service.submit(sweep("paged.zarr", realisations=2, name="paged"))
    assert status == 201
    assert open_service.wait(job["id"], finished)["state"] == "succeeded"
    listing = chromium("--dump-dom", open_service.url + "/", folder=tmp_path)
    assert job["id"] in listing and "paged" in listing and "<progress" in listing
    page = chromium("--dump-dom", f"{open_service.url}/jobs/{job['id']}", folder=tmp_path)
    assert "succeeded" in page and "target.shape" in page  # its parameters
    assert f"/jobs/{job['id']}/statistics.png" in page and f"/jobs/{job['id']}/preview.png" in page
    for picture in ("statistics", "preview"):  # drawn (the page has loaded): no placeholder
        assert re.search(f'<p class="placeholder" id="{picture}-placeholder" hidden', page)
    for picture in ("statistics", "preview"):
        with urllib.request.urlopen(f"{open_service.url}/jobs/{job['id']}/{picture}.png") as r:
            assert r.headers["content-type"] == "image/png"
            assert r.read(8) == b"\x89PNG\r\n\x1a\n"
    shot = tmp_path / "page.png"
    chromium(
        f"--screenshot={shot}",
        "--window-size=900,1400",
        f"{open_service.url}/jobs/{job['id']}",
        folder=tmp_path,
    )
    assert shot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_token_files_name_each_owner_and_each_token_once(tmp_path):
    from service.errors import InputError
    from service.guards import read_tokens

    tokens = tmp_path / "tokens"
    tokens.write_text("# owner token\nalice a-1\nbob b-2\n")
    assert read_tokens(str(tokens)) == {"alice": "a-1", "bob": "b-2"}
    for text, twice in [
        ("alice a-1\nalice b-2\n", "owner"),
        ("alice a-1\nbob a-1\n", "token"),
        ("t-1\nt-2\n", "owner"),  # two tokens of the owner 'default'
    ]:
        tokens.write_text(text)
        with pytest.raises(InputError, match=f"each {twice} may appear on one line only"):
            read_tokens(str(tokens))


def test_outputs_stay_under_the_data_root(tmp_path):
    from service.admission import confine_output
    from service.errors import InputError

    root = tmp_path / "data"
    root.mkdir()
    assert confine_output("runs/a.zarr", str(root)) == f"{root}/runs/a.zarr"
    os.symlink(tmp_path, root / "link")
    for output in [*ESCAPES, "memory::a.zarr", "a.zarr::s3://bucket", ".", "a/../.."]:
        with pytest.raises(InputError, match=r"^output: "):
            confine_output(output, str(root))
    # a link that leads inside the data root is refused too (issue #37 item 10)
    (root / "real").mkdir()
    os.symlink(root / "real", root / "inner")
    os.symlink(root / "real" / "b.zarr", root / "real" / "c.zarr")
    assert confine_output("real/a.zarr", str(root)) == f"{root}/real/a.zarr"
    for output, link in [("inner/a.zarr", "inner"), ("real/c.zarr", "real/c.zarr")]:
        with pytest.raises(InputError, match=f"^output: .* the symbolic link '{link}'"):
            confine_output(output, str(root))


def test_a_link_planted_after_admission_leads_no_job_out(tmp_path, session_cluster):
    """Issue #37 item 10: the output is confined again as the job starts."""
    from service.jobs import Runner
    from service.table import JobTable

    data, outside = tmp_path / "data", tmp_path / "outside"
    (data / "runs").mkdir(parents=True)
    outside.mkdir()
    table = JobTable(str(tmp_path / "jobs.sqlite"))
    runner = Runner(
        table,
        session_cluster,
        data_root=Store(str(data)),
        max_running=0,  # validated and queued, not started
        queue_limit=10,
        batch_size=1,
    )
    runner.start()
    try:
        job, _ = runner.submit(sweep("runs/x.zarr", realisations=1), owner="alice")
        deadline = time.monotonic() + 60
        while table.get(job.id).state != "queued" and time.monotonic() < deadline:
            time.sleep(0.05)
        assert table.get(job.id).state == "queued"
        (data / "runs").rmdir()
        os.symlink(outside, data / "runs")
        runner.max_running = 1
        while not table.get(job.id).state.final and time.monotonic() < deadline + 60:
            time.sleep(0.05)
    finally:
        runner.stop()
    job = table.get(job.id)
    assert job.state == "failed", job
    assert job.message == "output: 'runs/x.zarr' leads out of the service's data root", job
    assert os.listdir(outside) == []


def test_an_object_storage_data_root_reads_no_measurement_file():
    from service.errors import InputError
    from service.sweep import parse_sweep

    text = sweep("x.zarr").replace("surface: {", "surface: {conditioning: {file: points.csv}, ")
    with pytest.raises(InputError, match=r"^scene\.surface\.conditioning\.file: .*local folder"):
        parse_sweep(text, folder="s3://bucket/oceanlidar")


def test_one_service_a_table_and_no_store_inside_another(tmp_path):
    from service.errors import InputError
    from service.jobs import Runner
    from service.table import JobTable

    table = JobTable(str(tmp_path / "jobs.sqlite"))
    with pytest.raises(InputError, match="another oceanlidar serve uses this job table"):
        JobTable(str(tmp_path / "jobs.sqlite"))
    (tmp_path / "data" / "done.zarr").mkdir(parents=True)
    group = {"zarr_format": 3, "node_type": "group", "attributes": {}}
    (tmp_path / "data" / "done.zarr" / "zarr.json").write_text(json.dumps(group))
    runner = Runner(
        table,
        None,
        data_root=Store(str(tmp_path / "data")),
        max_running=0,  # nothing runs: jobs are validated, not started
        queue_limit=10,
        batch_size=1,
    )
    runner.start()
    try:
        runner.submit(sweep("runs/a.zarr"), owner="alice")
        # a conflict with another job is 409 (issue #27), a path the service refuses 400
        for output, reason, status in [
            ("runs/a.zarr", "the same store or one inside the other", 409),
            ("runs/a.zarr/image.zarr", "the same store or one inside the other", 409),
            ("runs", "the same store or one inside the other", 409),
            ('"a\\0b.zarr"', "control characters", 400),
        ]:
            with pytest.raises(InputError, match=f"^output: .*{re.escape(reason)}") as refused:
                runner.submit(sweep(output), owner="bob")
            assert refused.value.status == status, output
        assert len(table.list()) == 1
        inside, _ = runner.submit(sweep("done.zarr/b/c.zarr"), owner="bob")  # found later
        job, _ = runner.submit(sweep("runs/b.zarr"), owner="bob")
        assert job.state == "validating"
        deadline = time.monotonic() + 60
        while table.get(job.id).state == "validating" and time.monotonic() < deadline:
            time.sleep(0.05)
    finally:
        runner.stop()
    assert table.get(job.id).state == "queued"
    inside = table.get(inside.id)
    assert inside.state == "rejected", inside
    assert re.match(r"^output: .*lies inside the store 'done.zarr'", inside.message), inside


@pytest.mark.parametrize("link", [os.symlink, os.link], ids=["symbolic", "hard"])
def test_one_service_a_table_whatever_path_reaches_it(tmp_path, link):
    from service.errors import InputError
    from service.table import JobTable

    table = JobTable(str(tmp_path / "jobs.sqlite"))
    link(tmp_path / "jobs.sqlite", tmp_path / "linked.sqlite")
    with pytest.raises(InputError, match="another oceanlidar serve uses this job table"):
        JobTable(str(tmp_path / "linked.sqlite"))
    assert table.lost() is None
    (tmp_path / "jobs.sqlite").unlink()  # a table lost while served is noticed
    assert "is gone" in table.lost()


@pytest.mark.parametrize("how", ["copied over", "truncated"])
def test_a_job_table_overwritten_in_place_is_lost(tmp_path, how):
    """Issue #37 item 11: ``cp other.sqlite jobs.sqlite`` and ``truncate -s 0`` keep the
    file (its inode) and change what it holds: noticed, and for good."""
    from service.records import Job, JobState
    from service.table import JobTable

    path = tmp_path / "jobs.sqlite"
    table = JobTable(str(path))
    job = Job(
        id="0123456789ab",
        owner="alice",
        name="x",
        state=JobState.QUEUED,
        mode="new",
        sweep="",
        output="x.zarr",
        url="x.zarr",
        submitted=time.time(),
        total=1,
    )
    table.add(job)
    assert table.lost() is None and table.get(job.id) is not None
    inode = path.stat().st_ino
    shutil.copyfile(path, tmp_path / "saved.sqlite")
    if how == "copied over":
        JobTable(str(tmp_path / "other.sqlite"))  # another service's table
        shutil.copyfile(tmp_path / "other.sqlite", path)
    else:
        os.truncate(path, 0)
    assert path.stat().st_ino == inode
    assert "was overwritten or truncated in place" in table.lost()
    shutil.copyfile(tmp_path / "saved.sqlite", path)  # nor trusted once put back
    assert "was overwritten or truncated in place" in table.lost()


def test_a_lost_job_table_stops_the_service_and_stores_keep_their_owner(tmp_path):
    (tmp_path / "tokens").write_text(f"alice {TOKEN}\nbob {OTHER_TOKEN}\n")
    server = Server(tmp_path, "--token-file", tmp_path / "tokens")
    text = sweep("owned.zarr", realisations=1)
    try:
        server.start()
        job = server.submit(text)[1]
        assert server.wait(job["id"], finished)["state"] == "succeeded"
        (tmp_path / "jobs.sqlite").unlink()
        status, answer = server.request("GET", "/v1/health")
        assert status == 503 and "is gone" in answer["error"], answer
        assert server.submit(sweep("more.zarr"))[0] == 503
        server.stop()
        server.start()  # on a new table: the jobs are forgotten, not who owns the store
        assert server.request("GET", "/v1/jobs")[1]["jobs"] == []
        for mode in ("resume", "overwrite"):
            status, refused = server.request(
                "POST", f"/v1/jobs?mode={mode}", text.encode(), token=OTHER_TOKEN
            )
            assert status == 403 and "written by alice" in refused["error"], refused
        status, again = server.submit(text, mode="overwrite")
        assert status == 201
        assert server.wait(again["id"], finished)["state"] == "succeeded"
        assert Store(job["url"]).attributes()[OWNER] == "alice"
    finally:
        server.stop()


def test_a_job_writing_its_statistics_can_no_longer_be_cancelled(tmp_path, threads, monkeypatch):
    from service.cluster import dask_client
    from service.jobs import Runner
    from service.table import JobTable

    writing, release = threading.Event(), threading.Event()
    write_statistics = threads.write_statistics

    def held(store, **options):
        writing.set()
        release.wait(120)
        return write_statistics(store, **options)

    monkeypatch.setattr(threads, "write_statistics", held)
    (tmp_path / "data").mkdir()
    with dask_client(workers=1, scheduler=None) as cluster:
        runner = Runner(
            JobTable(str(tmp_path / "jobs.sqlite")),
            cluster,
            data_root=Store(str(tmp_path / "data")),
            max_running=1,
            queue_limit=10,
            batch_size=1,
        )
        runner.start()
        try:
            job, _ = runner.submit(sweep("late.zarr", realisations=1), owner="alice")
            assert writing.wait(120)
            assert not runner.cancel(job.id)  # the samples are written: too late
            # and the job, its page and `status` say what it does (issue #37 item 13)
            held = runner.table.get(job.id)
            assert (held.state, held.phase) == ("running", "writing statistics"), held
            page = job_page(held, viewer="alice", csrf="0" * 64)
            assert "<span data-field='state'>running: writing statistics</span>" in page
            assert "<span data-field='left'>0 s (writing statistics)</span>" in page
            assert "cancel the job" not in page
            assert ", writing statistics  " in _line(held.public())
            release.set()
            deadline = time.monotonic() + 120
            while not runner.table.get(job.id).state.final and time.monotonic() < deadline:
                time.sleep(0.05)
        finally:
            release.set()
            runner.stop()
    assert runner.table.get(job.id).state == "succeeded"
    assert runner.table.get(job.id).phase is None
    assert Store(job.url).stats.attributes()[KIND] == "statistics"
    assert "writing the statistics" in " ".join(
        line["message"] for line in runner.table.lines(job.id)
    )


@pytest.mark.parametrize(
    "state, rate, left",
    [
        ("succeeded", "2.50 samples/s", "0 s"),
        ("cancelled", "2.50 samples/s", "none (cancelled)"),
        ("failed", "2.50 samples/s", "none (failed)"),
        ("queued", "-", "-"),
    ],
)
def test_a_finished_jobs_page_shows_its_rate_and_no_time_left(state, rate, left):
    """Issue #37 item 13: a finished job showed "-" for both; a succeeded one's pictures
    show a placeholder until they are drawn (seconds, the first time)."""
    from service.records import Job, JobState

    job = Job(
        id="0123456789ab",
        owner="alice",
        name="x",
        state=JobState(state),
        mode="new",
        sweep="",
        output="x.zarr",
        url="x.zarr",
        submitted=100.0,
        started=None if state == "queued" else 110.0,
        finished=None if state == "queued" else 130.0,
        total=50,
        done=0 if state == "queued" else 50,
        rate=0.0 if state == "queued" else 2.5,
    )
    page = job_page(job, viewer="alice", csrf="0" * 64)
    assert f"<span data-field='rate'>{rate}</span>" in page
    assert f"<span data-field='left'>{left}</span>" in page
    placeholders = re.findall(r"<p class='placeholder' id='(\w+)-placeholder'>drawing", page)
    assert placeholders == (["statistics", "preview"] if state == "succeeded" else [])
    assert ('<script src="/job.js"' in page) == (state in ("succeeded", "queued"))


def get_concurrently(url, paths, headers=None):
    """GET every one of `paths` at once, each in its own thread: (status, type, head) each."""
    answers = [None] * len(paths)

    def get(index):
        request = urllib.request.Request(url + paths[index], headers=headers or {})
        with urllib.request.urlopen(request, timeout=120) as answer:
            answers[index] = (answer.status, answer.headers["content-type"], answer.read(8))

    getters = [threading.Thread(target=get, args=(index,)) for index in range(len(paths))]
    for getter in getters:
        getter.start()
    for getter in getters:
        getter.join(timeout=180)
    return answers


PNG = (200, "image/png", b"\x89PNG\r\n\x1a\n")


def test_concurrent_views_of_a_picture_draw_it_once(reference, tmp_path, monkeypatch):
    """Eight requests for one job's preview render its samples once (in this process)."""
    import uvicorn

    import service.plots
    from service.jobs import Runner
    from service.records import Job, JobState
    from service.server import create_app
    from service.table import JobTable

    renders = []
    render_preview = service.plots.render_preview

    def counted(plan, sample):
        renders.append(sample)
        return render_preview(plan, sample)

    monkeypatch.setattr(service.plots, "render_preview", counted)
    table = JobTable(str(tmp_path / "jobs.sqlite"))
    text = sweep("reference.zarr")
    table.add(
        Job(
            id="0123456789ab",
            owner="anonymous",
            name="served",
            state=JobState.SUCCEEDED,
            mode="new",
            sweep=text,
            output="reference.zarr",
            url=str(reference),
            submitted=time.time(),
            total=2 * LONG,
        )
    )
    root = Store(str(reference.parent))
    runner = Runner(table, None, data_root=root, max_running=1, queue_limit=1, batch_size=1)
    config = uvicorn.Config(
        create_app(runner, {}), host="127.0.0.1", port=free_port(), log_level="warning"
    )
    server = uvicorn.Server(config)
    serving = threading.Thread(target=server.run)
    serving.start()
    try:
        while not server.started and serving.is_alive():
            time.sleep(0.05)
        url = f"http://127.0.0.1:{config.port}/jobs/0123456789ab"
        assert get_concurrently(url, ["/preview.png"] * 8) == [PNG] * 8
        assert renders == [0, 1, 2]
        assert get_concurrently(url, ["/preview.png"]) == [PNG] and len(renders) == 3
    finally:
        server.should_exit = True
        serving.join(timeout=30)


def test_a_fresh_servers_first_views_of_both_pictures_answer(tmp_path):
    """The first requests after a start, two for each picture at once, all draw (#27 item 2)."""
    server = Server(tmp_path)
    try:
        server.start()
        job = server.submit(sweep("viewed.zarr", realisations=1))[1]
        assert server.wait(job["id"], finished)["state"] == "succeeded"
        pictures = [f"/jobs/{job['id']}/{kind}.png" for kind in ("statistics", "preview") * 2]
        token = {"Authorization": f"Bearer {TOKEN}"}
        assert get_concurrently(server.url, pictures, token) == [PNG] * 4
    finally:
        server.stop()


def test_pictures_keep_at_most_their_bytes(monkeypatch):
    import asyncio
    from types import SimpleNamespace

    from service import pictures

    drawn = []

    def draw(job, data_root):
        drawn.append(job.id)
        return b"x" * 10

    monkeypatch.setitem(pictures.KINDS, "statistics", draw)
    kept = pictures.Pictures(Store("/nowhere"), max_bytes=25)
    jobs = [SimpleNamespace(id=str(n)) for n in range(3)]

    async def view(order):
        for job in order:
            assert await kept.get(job, "statistics") == b"x" * 10

    asyncio.run(view([*jobs, jobs[1], jobs[2], jobs[0]]))
    assert drawn == ["0", "1", "2", "0"]  # two pictures fit: the oldest went
