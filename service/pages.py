"""The job service's web pages: the job list, a job's page and its live view.

HTML built from the `service.records.Job`s the server reads, every text escaped. A job's
page fits a 1000 px window (long paths and sweeps wrap, pictures shrink to its width) and
shows its state (with its phase: ``writing statistics``), progress, rate, time left, start
and elapsed times, and once it has succeeded its pictures, each behind a placeholder until
it is drawn; while the job is unfinished `SCRIPT` (served by the service itself, as its
content security policy asks) follows the job's event stream (``GET /v1/jobs/ID/events``)
instead of reloading the page. Its owner cancels it with a form that carries a token
derived from the login cookie (`csrf_token`): another site's page can neither read that
token nor send the cookie.
"""

from __future__ import annotations

import hashlib
import hmac
import html
import json
import time
import urllib.parse

from starlette.requests import ClientDisconnect, Request
from starlette.responses import JSONResponse

from service.records import Job, JobState

__all__ = [
    "LOGIN_FORM",
    "SCRIPT",
    "csrf_token",
    "job_page",
    "list_page",
    "page",
    "read_form",
    "same_origin",
]

LOGIN_FORM = (
    '<form method="post" action="/login"><label>token <input type="password" name="token">'
    "</label> <button>log in</button></form>"
)
STYLE = (
    "body{font-family:sans-serif;margin:1em auto;max-width:60em;padding:0 1em}"
    "td,th{padding:0.2em 0.8em;text-align:left;vertical-align:top}"
    "pre{background:#f4f4f4;padding:1em;white-space:pre-wrap;overflow-wrap:anywhere}"
    "code{overflow-wrap:anywhere}img{max-width:100%;height:auto}progress{width:10em}"
    "table{border-collapse:collapse;max-width:100%}.facts th{font-weight:normal;color:#555}"
)
"""Nothing wider than the window: text wraps, pictures shrink."""
_SCRIPT = """\
"use strict";
// A job's page follows the job's event stream (GET /v1/jobs/ID/events), no reloads.
const page = document.querySelector("[data-job]");
const FINAL = __FINAL__;
let job = null;

function duration(seconds) {
  if (seconds === null || seconds === undefined || !isFinite(seconds)) return "-";
  seconds = Math.max(0, Math.round(seconds));
  const h = Math.floor(seconds / 3600), m = Math.floor((seconds % 3600) / 60);
  return (h ? h + " h " : "") + (h || m ? m + " min " : "") + (seconds % 60) + " s";
}

function when(epoch) {
  if (!epoch) return "-";
  return new Date(epoch * 1000).toISOString().replace("T", " ").slice(0, 19) + " UTC";
}

function set(field, text) {
  const element = page.querySelector(`[data-field="${field}"]`);
  if (element) element.textContent = text;
}

// as job_page writes them (service/pages.py: shown_state, shown_rate, shown_left)
function left() {
  if (job.phase) return `0 s (${job.phase})`;
  if (job.state === "running") return duration(job.seconds_left);
  if (job.state === "succeeded") return "0 s";
  return FINAL.includes(job.state) ? `none (${job.state})` : "-";
}

function show() {
  const bar = page.querySelector("progress");
  bar.max = job.samples.total;
  bar.value = job.samples.done;
  set("state", job.phase ? `${job.state}: ${job.phase}` : job.state);
  set("samples", `${job.samples.done}/${job.samples.total} samples`);
  set("rate", job.rate > 0 ? `${job.rate.toFixed(2)} samples/s` : "-");
  set("left", left());
  set("started", when(job.started));
  const end = job.finished || Date.now() / 1000;
  set("elapsed", job.started ? duration(end - job.started) : "-");
  const cancel = page.querySelector("form.cancel");
  if (cancel && job.phase) cancel.hidden = true;  // too late to cancel
}

// a picture is drawn the first time it is asked for: its placeholder says so until then
for (const picture of document.querySelectorAll("img[data-picture]")) {
  const note = document.getElementById(`${picture.id}-placeholder`);
  const drawn = () => { note.hidden = true; };
  const failed = () => { note.textContent = `the ${picture.alt} could not be drawn`; };
  if (picture.complete) {
    (picture.naturalWidth ? drawn : failed)();
  } else {
    picture.addEventListener("load", drawn);
    picture.addEventListener("error", failed);
  }
}

if (page && !FINAL.includes(page.dataset.state)) {
  const events = new EventSource(`/v1/jobs/${page.dataset.job}/events`);
  events.addEventListener("progress", (event) => {
    job = JSON.parse(event.data);
    show();
    if (FINAL.includes(job.state)) {
      events.close();
      location.reload();  // once: the finished page shows its pictures or errors
    }
  });
  setInterval(() => job && show(), 1000);  // the elapsed time runs between events
}
"""
SCRIPT = _SCRIPT.replace(
    "__FINAL__", json.dumps([state.value for state in JobState if state.final])
)
"""The job page's live view (served at ``/job.js``); it stops at the final states."""


def csrf_token(secret: bytes, credential: str) -> str:
    """The token a page's form carries: HMAC-SHA256 of the login `credential` (hex).

    Parameters
    ----------
    secret : bytes
        The service's own key, drawn when it starts (forms of a previous run are refused).
    credential : str
        The login cookie's value (the user's token); empty for a service without tokens.
    """
    return hmac.new(secret, b"cancel\0" + credential.encode(), hashlib.sha256).hexdigest()


def when(seconds: float | None) -> str:
    """An epoch time (s) as UTC to the second; ``-`` for none."""
    if seconds is None:
        return "-"
    return time.strftime("%Y-%m-%d %H:%M:%S", time.gmtime(seconds)) + " UTC"


def duration(seconds: float | None) -> str:
    """A duration (s) as hours, minutes and seconds, as `SCRIPT` writes it; ``-`` for none."""
    if seconds is None:
        return "-"
    seconds = max(0, round(seconds))
    hours, minutes = seconds // 3600, seconds % 3600 // 60
    shown = f"{hours} h " if hours else ""
    shown += f"{minutes} min " if hours or minutes else ""
    return shown + f"{seconds % 60} s"


def shown_state(job: Job) -> str:
    """A job's state as its page shows it, with its phase (``running: writing statistics``)."""
    return f"{job.state}: {job.phase}" if job.phase else str(job.state)


def shown_rate(job: Job) -> str:
    """A job's rate (samples/s of its run) as its page shows it, finished or not."""
    return f"{job.rate:.2f} samples/s" if job.rate > 0 else "-"


def shown_left(job: Job) -> str:
    """A job's time left as its page shows it.

    None once finished (0 s if it succeeded), 0 s while its statistics are written, ``-``
    while nothing says.
    """
    if job.phase:
        return f"0 s ({job.phase})"
    if job.state is JobState.RUNNING:
        return duration(job.public()["seconds_left"])
    if job.state is JobState.SUCCEEDED:
        return "0 s"
    return f"none ({job.state})" if job.state.final else "-"


def page(title: str, body: str, *, refresh: bool = False, script: bool = False) -> str:
    """A whole page; `refresh` reloads it every 3 s, `script` loads `SCRIPT`.

    `SCRIPT` is the live view and hides the pictures' placeholders once they are drawn.
    """
    meta = '<meta http-equiv="refresh" content="3">' if refresh else ""
    meta += '<script src="/job.js" defer></script>' if script else ""
    return (
        "<!doctype html><html><head><meta charset='utf-8'>"
        "<meta name='viewport' content='width=device-width'>"
        f"{meta}<title>{title}</title><style>{STYLE}</style></head><body>"
        f"<h1><a href='/'>oceanlidar</a></h1><h2>{title}</h2>{body}</body></html>"
    )


def list_page(jobs: list[Job]) -> str:
    """Every job with its progress, newest first; reloaded every 3 s while one runs."""
    rows = "".join(
        f"<tr><td><a href='/jobs/{j.id}'>{j.id}</a></td><td>{html.escape(j.name)}"
        f"</td><td>{html.escape(j.owner)}</td><td class='state'>{j.state}</td>"
        f"<td><progress value='{j.done}' max='{j.total}'></progress> "
        f"{j.done}/{j.total}</td><td>{when(j.submitted)}</td></tr>"
        for j in jobs
    )
    table = (
        "<table><tr><th>job</th><th>sweep</th><th>owner</th><th>state</th>"
        f"<th>samples</th><th>submitted</th></tr>{rows}</table>"
    )
    return page("oceanlidar jobs", table, refresh=any(not j.state.final for j in jobs))


def job_page(job: Job, *, viewer: str, csrf: str) -> str:
    """A job's page as `viewer` sees it: facts, cancel form (its owner's), pictures, sweep.

    Parameters
    ----------
    job : Job
        The job.
    viewer : str
        Who asks (the owner of the request's credential): only the job's owner sees the
        cancel button of an unfinished job.
    csrf : str
        The viewer's `csrf_token`, carried by the cancel form.
    """
    end = job.finished or time.time()
    facts = [
        ("state", f"<span data-field='state'>{shown_state(job)}</span>"),
        (
            "progress",
            f"<progress value='{job.done}' max='{job.total}'></progress> "
            f"<span data-field='samples'>{job.done}/{job.total} samples</span>",
        ),
        ("rate", f"<span data-field='rate'>{shown_rate(job)}</span>"),
        ("time left", f"<span data-field='left'>{shown_left(job)}</span>"),
        ("submitted", when(job.submitted)),
        ("started", f"<span data-field='started'>{when(job.started)}</span>"),
        (
            "elapsed",
            f"<span data-field='elapsed'>"
            f"{duration(end - job.started) if job.started else '-'}</span>",
        ),
        ("owner", html.escape(job.owner)),
        ("output", f"<code>{html.escape(job.url)}</code>"),
    ]
    rows = "".join(f"<tr><th>{name}</th><td>{value}</td></tr>" for name, value in facts)
    parts = [f"<table class='facts'>{rows}</table>"]
    if not job.state.final and viewer == job.owner and not job.phase:
        parts.append(
            f"<form class='cancel' method='post' action='/jobs/{job.id}/cancel'>"
            f"<input type='hidden' name='csrf' value='{csrf}'>"
            "<button>cancel the job</button></form>"
        )
    if job.message:
        parts.append(f"<p class='message'>{html.escape(job.message)}</p>")
    if job.errors:
        errors = "".join(f"<li>sample {s}: {html.escape(r)}</li>" for s, r in job.errors.items())
        parts.append(f"<ul class='errors'>{errors}</ul>")
    if job.state is JobState.SUCCEEDED:
        parts += [
            f"<h2>{heading}</h2><p class='placeholder' id='{kind}-placeholder'>drawing the "
            f"{alt} (a few seconds, the first time it is shown)…</p><img id='{kind}' "
            f"data-picture src='/jobs/{job.id}/{kind}.png' alt='{alt}'>"
            for heading, kind, alt in (
                ("statistics", "statistics", "statistics plot"),
                ("first samples", "preview", "preview strip"),
            )
        ]
    parts.append(f"<h2>sweep</h2><pre class='sweep'>{html.escape(job.sweep)}</pre>")
    body = f"<div data-job='{job.id}' data-state='{job.state}'>{''.join(parts)}</div>"
    title = f"oceanlidar job {job.id}: {html.escape(job.name)}"
    live = not job.state.final or job.state is JobState.SUCCEEDED  # events, or placeholders
    return page(title, body, script=live)


def same_origin(headers, *, required: bool = True) -> bool:
    """Whether a request comes from this service's own pages (``Origin``, ``Sec-Fetch-Site``).

    Browsers send ``Origin`` with every ``POST``: one that names another host is another
    site's, as is a ``Sec-Fetch-Site`` other than ``same-origin`` (or ``none``, a request the
    user made). ``Origin: null`` is what a sandboxed frame of any site sends (and every form,
    under ``Referrer-Policy: no-referrer``): it passes only where the browser vouches for
    the page with ``Sec-Fetch-Site: same-origin``, a header no page can set. With
    `required`, a request with neither header (it came from no browser page) is refused too
    (scripts cancel through the API's ``DELETE`` with a token); without, it passes (the
    API's clients are no browsers).

    Parameters
    ----------
    headers : Mapping
        The request's headers (lower-case names).
    required : bool, optional
        Whether a request must say where it comes from.
    """
    origin, site = headers.get("origin"), headers.get("sec-fetch-site")
    if origin is None and site is None:
        return not required
    if site not in (None, "same-origin", "none"):
        return False
    if origin == "null":
        return site == "same-origin"
    return origin is None or urllib.parse.urlsplit(origin).netloc == headers.get("host")


FORM_BYTES = 4096
"""Longest form accepted (log-in, cancel), bytes."""


async def read_form(request: Request) -> dict[str, str] | JSONResponse:
    """A page's form (`FORM_BYTES` at most), each field's first value; or the refusal."""
    length = request.headers.get("content-length", "")
    if not length.isdigit():
        return JSONResponse({"error": "a form needs its Content-Length"}, status_code=400)
    if int(length) > FORM_BYTES:
        return JSONResponse({"error": f"a form has at most {FORM_BYTES} bytes"}, status_code=413)
    try:
        fields = urllib.parse.parse_qs((await request.body()).decode(errors="replace"))
    except ClientDisconnect:  # nobody to answer
        return JSONResponse({"error": "the client went away"}, status_code=400)
    return {name: values[0] for name, values in fields.items()}
