"""What long commands show on stderr: set-up phases, then the work done of its total."""

import io
import os
import pty
import re

from conftest import TINY_SWEEP

from service import progress
from service.progress import Progress

PHASE = r"\.\.\. \d+\.\d s$"
"""How a phase line ends: its duration."""


def lines(text: str) -> list[str]:
    return text.splitlines()


def first_index(found: list[str], pattern: str) -> int:
    """Index of the first line matching `pattern` (a failure names what is missing)."""
    matches = [i for i, line in enumerate(found) if re.search(pattern, line)]
    assert matches, f"no line matches {pattern!r} in {found}"
    return matches[0]


def test_a_run_shows_its_phases_then_its_progress_and_its_total(tmp_path, cli, shared_cluster):
    # issue #27, item 6: `run` was silent for 100 s before its first progress line
    sweep = tmp_path / "t.yaml"
    sweep.write_text(TINY_SWEEP.format(name="t", seed=4, realisations=3, output="t.zarr"))
    result = cli("run", sweep, "--workers", "1", "--batch", "2", cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    err = lines(result.stderr)
    cluster = first_index(err, r"^starting the local cluster \(1 worker\)" + PHASE)
    workers = first_index(err, r"^waiting for the workers to start and see the store" + PHASE)
    template = first_index(err, r"^writing the store template" + PHASE)
    first = first_index(err, r"^rendering the first shard" + PHASE)
    # stderr is no terminal here: a log's plain line, its last with the total
    total = first_index(err, r"^100%\|#+\| 6/6 \[\d\d:\d\d<00:00, +[\d.]+(s/)? samples(/s)?\]$")
    stats = first_index(err, r"^writing the statistics" + PHASE)
    assert cluster < workers < template < first < total < stats
    assert sum("6/6" in line for line in err) == 1  # the total once, not again at the end


def test_stats_and_plot_show_their_progress_and_quiet_shows_none(tmp_path, cli, shared_cluster):
    sweep = tmp_path / "t.yaml"
    sweep.write_text(TINY_SWEEP.format(name="t", seed=4, realisations=2, output="t.zarr"))
    assert cli("-q", "run", sweep, "--workers", "1", cwd=tmp_path).returncode == 0
    result = cli("stats", "t.zarr", cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    first_index(
        lines(result.stderr), r"^100%\|#+\| 2/2 \[\d\d:\d\d<00:00, +[\d.]+(s/)? points(/s)?\]$"
    )
    result = cli("plot", "t.zarr", "--output", "s.png", cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    err = lines(result.stderr)
    assert first_index(err, "^reading the statistics" + PHASE) < first_index(
        err, "^drawing s.png" + PHASE
    )
    for command in (("stats", "t.zarr"), ("plot", "t.zarr", "--output", "s.png")):
        assert cli("-q", *command, cwd=tmp_path).stderr == ""


def test_a_log_gets_a_line_at_times_and_one_with_the_total():
    stream, calls = io.StringIO(), []
    shown = Progress(
        5,
        unit="samples",
        already=2,
        stream=stream,
        callback=lambda done, rate: calls.append(done),
        first="first shard",
    )
    assert stream.getvalue() == "first shard... "
    shown.update(1)
    # the first result ends the phase line; the next line waits for LOG_EVERY or the end
    assert re.fullmatch(r"first shard\.\.\. \d+\.\d s\n", stream.getvalue())
    shown.update(2)
    shown.close()
    written = lines(stream.getvalue())
    assert len(written) == 2 and re.match(r"100%\|#+\| 5/5 \[", written[1])
    assert calls == [3, 5]  # the job service's callback: every update, done in all


def test_a_log_line_every_interval_and_the_count_at_an_early_close(monkeypatch):
    monkeypatch.setattr(progress, "LOG_EVERY", 0.0)
    stream = io.StringIO()
    shown = Progress(4, unit="points", stream=stream)
    shown.update(1)
    shown.update(1)
    assert [line.split("|")[2][:4] for line in lines(stream.getvalue())] == [" 1/4", " 2/4"]
    monkeypatch.setattr(progress, "LOG_EVERY", 1e9)
    shown.update(1)
    shown.close()  # interrupted: the log still says how far it got
    assert lines(stream.getvalue())[-1].split("|")[2].startswith(" 3/4")


def test_a_terminal_of_no_width_gets_the_log_lines():
    # a trial of issue #27: a pseudo-terminal that says it has 0 columns (`script`, some
    # `docker -t` and CI terminals) showed no progress at all: tqdm drew its bar 0 wide
    main, secondary = pty.openpty()  # a new pseudo-terminal: 0 rows, 0 columns
    with os.fdopen(secondary, "w") as terminal:
        shown = Progress(3, unit="samples", stream=terminal)
        shown.update(3)
        shown.close()
    written = os.read(main, 4096).decode()
    os.close(main)
    assert re.search(r"100%\|#+\| 3/3 \[", written), written


def test_no_stream_writes_nothing_and_a_stopped_phase_says_so(capsys):
    shown = Progress(2, unit="samples", first="first shard")
    shown.update(2)
    shown.close()
    stream = io.StringIO()
    try:
        with progress.phase("writing", stream=stream):
            raise KeyError("x")
    except KeyError:
        pass
    assert re.fullmatch(r"writing\.\.\. stopped after \d+\.\d s\n", stream.getvalue())
    assert capsys.readouterr() == ("", "")
