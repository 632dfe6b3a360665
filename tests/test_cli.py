"""Command-line conventions: --version, -v/-q logging, --dashboard, schema, validate, preview."""

import json
import os
import socket
import subprocess
import warnings
from pathlib import Path

import dask
import jsonschema
import numpy as np
import pytest
import xarray as xr
import yaml
from conftest import ROOT, TINY_SWEEP, batch_of, cli_command, run_cli, start_cli
from dask.utils import format_time

from service import package_version, plots
from service.cli import main
from service.cli.parser import parser
from service.cli.run_commands import run_time
from service.cluster import QUIET, dask_client
from service.run import render_shard, task_batches
from service.schema import sweep_json_schema
from service.store.layout import shard_size
from service.store.location import Store
from service.store.template import create_store
from service.sweep import load_sweep, parse_sweep
from workers.render import render_arrays
from workers.settings.scene import Scene

CONFIGS = sorted((ROOT / "configs").rglob("*.yaml"))


def tiny(folder: Path, realisations=2) -> Path:
    sweep = folder / "t.yaml"
    sweep.write_text(
        TINY_SWEEP.format(name="t", seed=4, realisations=realisations, output="t.zarr")
    )
    return sweep


def test_version(capsys):
    with pytest.raises(SystemExit) as stop:
        main(["--version"])
    assert stop.value.code == 0
    assert capsys.readouterr().out == f"oceanlidar {package_version()}\n"


@pytest.mark.parametrize("argv", ["--version", "--help", "run --help"])
def test_version_and_help_import_nothing_heavy(argv):
    # issue #27: `--version` took 2 s, the command line importing dask, xarray, zarr and
    # the renderer before it parsed anything; a command's module loads only when it runs
    heavy = ("dask", "distributed", "numba", "numpy", "pydantic", "xarray", "zarr", "workers")
    code = (
        "import sys\nfrom service.cli import main\n"
        f"try:\n    main({argv.split()!r})\nexcept SystemExit:\n    pass\n"
        f"print(sorted(set({heavy!r}) & set(sys.modules)), file=sys.stderr)"
    )
    command, env = cli_command()
    result = subprocess.run(
        [command[0], "-c", code], cwd=ROOT, env=env, capture_output=True, text=True, timeout=60
    )
    assert result.returncode == 0 and result.stderr.splitlines()[-1] == "[]", result.stderr


@pytest.mark.parametrize("path", CONFIGS, ids=[p.name for p in CONFIGS])
def test_the_schema_accepts_every_shipped_sweep(path, capsys):
    assert main(["schema"]) == 0
    schema = json.loads(capsys.readouterr().out)
    jsonschema.Draft202012Validator.check_schema(schema)
    jsonschema.validate(yaml.safe_load(path.read_text()), schema)


def test_the_schema_knows_the_scene_and_its_units():
    schema = sweep_json_schema()
    validator = jsonschema.Draft202012Validator(schema)
    good = yaml.safe_load(TINY_SWEEP.format(name="t", seed=1, realisations=1, output="o"))
    assert not list(validator.iter_errors(good))
    bad = {**good, "scene": {**good["scene"], "target": {"depht": 3.0}}}
    assert any("depht" in error.message for error in validator.iter_errors(bad))
    target = schema["$defs"]["Target"]["properties"]
    assert target["depth"]["units"] == "m" and target["x"]["units"] == "m"


def test_run_time_counts_the_start_once_each_scene_once_and_every_sample():
    times = {"setup": 1.0, "per_sample": 0.5, "workers": 2, "start": 4.0}
    assert run_time(samples=10, scenes=2, **times) == 4.0 + 3.5


def test_validate_counts_the_clusters_start_and_the_compilation(tmp_path, capsys, monkeypatch):
    # issue #27: the estimate left out the cluster's start and the kernels' compilation
    # (the first render's extra time was all counted as the scene's setup, over workers)
    import service.cli.run_commands as commands

    monkeypatch.setattr(commands, "_timed_render", lambda plan, point, backend: (2.0, 1.0, 0.5))
    assert main(["validate", str(tiny(tmp_path)), "--workers", "2"]) == 0
    out = capsys.readouterr().out
    # 4 samples of 2 scenes on 2 workers: start + compilation + (2 x 1 s + 4 x 0.5 s) / 2
    total = format_time(commands.CLUSTER_START + 2.0 + 2.0)
    assert f"  run time: about {total} on 2 worker(s)" in out, out
    assert f"the cluster starts in about {format_time(commands.CLUSTER_START)}" in out, out
    assert "the renderer compiles in 2.00 s" in out, out


def test_the_timed_render_tells_compilation_from_setup_and_sample(tmp_path, monkeypatch):
    # three renders of the first frame: cold, set up, caches emptied (kernels compiled)
    import service.cli.run_commands as commands

    clock = iter([0.0, 9.0, 10.0, 11.0, 20.0, 24.0])  # renders of 9, 1 and 4 s
    monkeypatch.setattr(commands.time, "perf_counter", lambda: next(clock))
    cleared = []
    monkeypatch.setattr(commands, "clear_all", lambda: cleared.append(True))
    plan = load_sweep(tiny(tmp_path))
    assert commands._timed_render(plan, 0) == (5.0, 3.0, 1.0) and cleared == [True]


def test_validate_estimates_the_run_and_shows_the_resolved_scene(tmp_path, capsys):
    sweep = tiny(tmp_path)
    assert main(["validate", str(sweep), "--show-scene", "--workers", "2"]) == 0
    out = capsys.readouterr().out
    assert "  run time: about " in out and "on 2 worker(s)" in out
    shown = yaml.safe_load(
        out.split("(units: `oceanlidar schema`)\n", 1)[1].split("  run time")[0]
    )
    scene = load_sweep(sweep).scenes[0]
    assert shown["water"]["theta0"] == 0.12 and shown["platform"]["altitude"] == 34.0
    assert Scene.model_validate(shown) == scene


def test_validate_says_the_batch_size_and_its_memory(tmp_path, capsys):
    # issue #39 item 5: the samples of a scene a task renders at once, the memory a batch
    # takes (the largest scene's, `service.batching.sample_memory` a sample) and the budget
    from dask.utils import format_bytes

    from service.batching import sample_memory

    sweep = tiny(tmp_path, realisations=16)  # 32 samples: shards of 4 (at least 8 shards)
    plan = load_sweep(sweep)
    largest = max(range(2), key=lambda point: sample_memory(plan.scenes[point]))
    per_sample = sample_memory(plan.scenes[largest])
    gib = 2.5 * per_sample / 2**30  # two samples fit
    assert main(["validate", str(sweep), "--no-estimate", "--batch-memory", str(gib)]) == 0
    out = capsys.readouterr().out
    assert (
        f"  batches: up to 2 samples of a scene at once on cpu, about "
        f"{format_bytes(2 * per_sample)} a batch ({format_bytes(per_sample)} a sample at "
        f"point {largest}, the largest)\n  batch memory: {format_bytes(gib * 2**30)} "
        "(--batch-memory)\n"
    ) in out, out
    # by default, half of a worker's share of this machine: a shard's 4 samples of a point
    assert main(["validate", str(sweep), "--no-estimate", "--workers", "2"]) == 0
    out = capsys.readouterr().out
    assert (
        f"  batches: up to 4 samples of a scene at once on cpu, about "
        f"{format_bytes(4 * per_sample)} a batch (" in out
    ), out
    assert "a shard holds 4 of a point)" in out, out
    assert (
        "  batch memory: " in out and "(50% of this machine's memory shared by 2 worker(s))" in out
    ), out


@pytest.mark.parametrize("value", ["0", "-1", "nan", "inf", "1e400"])
def test_a_batch_memory_that_is_no_size_is_refused(tmp_path, capsys, value, monkeypatch):
    import service.run

    monkeypatch.setattr(service.run, "execute", lambda *a, **k: pytest.fail("ran"))
    monkeypatch.chdir(tmp_path)
    serve = ["serve", "--no-auth", "--port", "1", "--db", "jobs.sqlite", "--data-root", "data"]
    for command in (["validate", "t.yaml"], ["run", "t.yaml"], serve):
        tiny(tmp_path)
        assert main([*command, "--batch-memory", value]) == 2
        error = capsys.readouterr().err
        assert (
            f"oceanlidar {command[0]}: error: --batch-memory must be a positive, finite number"
            in error
        )
    assert sorted(p.name for p in tmp_path.iterdir()) == ["t.yaml"]


def test_serve_passes_batch_memory_to_every_jobs_tasks(tmp_path, monkeypatch):
    # `serve --batch-memory GIB`: its runner runs every job with it (`Runner`, `execute`)
    import contextlib

    import service.jobs
    import service.server

    class GivenError(Exception):
        pass

    def runner(*args, **options):
        raise GivenError(options["batch_memory"])

    monkeypatch.setattr(service.server, "dask_client", lambda **o: contextlib.nullcontext())
    monkeypatch.setattr(service.server, "Runner", runner)
    monkeypatch.chdir(tmp_path)
    with socket.socket() as free:
        free.bind(("127.0.0.1", 0))
        port = str(free.getsockname()[1])
    serve = ["serve", "--no-auth", "--port", port, "--db", "j.sqlite", "--data-root", "data"]
    with pytest.raises(GivenError) as given:
        main([*serve, "--batch-memory", "0.25"])
    assert given.value.args == (2**28,)
    # and the runner runs each job's tasks with it
    from service.records import Job, JobState
    from service.table import JobTable

    ran = []

    def execute(plan, store, **options):
        ran.append(options["batch_memory"])
        raise RuntimeError("stop here")

    monkeypatch.setattr(service.jobs, "execute", execute)
    table = JobTable(str(tmp_path / "t.sqlite"))
    (tmp_path / "data").mkdir(exist_ok=True)
    root = Store.at(str(tmp_path / "data"))
    options = {"max_running": 1, "queue_limit": 1, "batch_size": None}
    runner = service.jobs.Runner(table, None, data_root=root, batch_memory=2**28, **options)
    text = TINY_SWEEP.format(name="j", seed=1, realisations=1, output="j.zarr")
    job = Job(
        "j1", "me", "j", JobState.RUNNING, "new", text, "j.zarr", f"{root.url}/j.zarr", 0.0, 2
    )
    table.add(job)
    runner._run(job, service.jobs.Cancel())
    assert ran == [2**28]
    assert "stop here" in table.get("j1").message


def test_run_passes_batch_memory_to_its_tasks(tmp_path, monkeypatch):
    # `run --batch-memory GIB`: the bytes every task's batches may take (`render_shard`'s)
    import service.run

    given = []

    def execute(plan, store, **options):
        given.append(options["batch_memory"])
        raise KeyboardInterrupt

    monkeypatch.setattr(service.run, "execute", execute)
    main(["run", str(tiny(tmp_path)), "--batch-memory", "1.5"])
    main(["run", str(tiny(tmp_path))])
    assert given == [1.5 * 2**30, None]


def test_validate_refuses_a_scene_that_renders_invalid_values(tmp_path, capsys, monkeypatch):
    # the render `validate` times is checked as `run` checks each sample before writing
    # it: a NaN there is a scene no sample of which would be written (a user trial found
    # a 10 m sphere and 30 /m water validated, then every sample refused)
    import service.cli.run_commands as commands

    def broken(scene, *, seed):
        arrays = render_arrays(scene, seed=seed)
        arrays["expected"][0, 0, 0, 0] = np.nan
        return arrays

    monkeypatch.setattr(commands, "render_samples", batch_of(broken))
    assert main(["validate", str(tiny(tmp_path)), "--workers", "1"]) != 0
    err = capsys.readouterr().err
    assert "renders invalid values: expected holds 1 non-finite value(s)" in err
    assert "Traceback" not in err


def test_quiet_runs_print_nothing_but_errors(tmp_path, capsys, shared_cluster):
    sweep = tiny(tmp_path, realisations=1)
    assert main(["-q", "run", str(sweep), "--workers", "1", "--output", str(tmp_path / "q")]) == 0
    assert capsys.readouterr().err == ""
    # --resume with nothing to resume starts a new run, and says so
    output = tmp_path / "r"
    assert main(["run", str(sweep), "--workers", "1", "--output", str(output), "--resume"]) == 0
    assert f"nothing at {output} to resume: starting a new run" in capsys.readouterr().err
    assert main(["run", str(sweep), "--workers", "1", "--output", str(output), "--resume"]) == 0
    assert "nothing at" not in capsys.readouterr().err


@pytest.mark.parametrize("verbose", [False, True], ids=["default", "verbose"])
def test_worker_warnings_stay_off_the_console_unless_verbose(capfd, verbose):
    with dask_client(workers=1, scheduler=None, verbose=verbose) as client:
        client.submit(warnings.warn, "a worker's warning", UserWarning, pure=False).result()
    assert ("a worker's warning" in capfd.readouterr().err) == verbose


def test_the_embedded_cluster_runs_without_the_dashboards_monitors():
    # the statistical profiler and fast monitors feed only the dashboard: off without it,
    # in the worker processes (which keep them when their nanny restarts them: a worker
    # killed for its memory, or crashed) and in the scheduler
    with dask_client(workers=1, scheduler=None) as client:
        settings = client.run(lambda: {key: dask.config.get(key) for key in QUIET})
        client.restart()
        restarted = client.run(lambda: {key: dask.config.get(key) for key in QUIET})
        ticks = client.run_on_scheduler(
            lambda dask_scheduler: dask_scheduler.periodic_callbacks["tick"].callback_time
        )
    assert list(settings.values()) == [QUIET]
    assert list(restarted.values()) == [QUIET]
    assert ticks == 1000.0  # ms
    assert dask.config.get("distributed.worker.profile.enabled")  # this process unchanged


def test_the_dashboard_link_is_printed_and_a_busy_port_is_not_reported(tmp_path):
    with socket.socket() as busy:
        try:
            busy.bind(("127.0.0.1", 8787))  # dask's default port, taken
            busy.listen()
        except OSError:
            pass  # someone else holds it: the same case
        result = run_cli("run", tiny(tmp_path, 1), "--workers", 1, "--dashboard", cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    assert "dashboard: http://127.0.0.1:" in result.stderr
    assert "8787" not in result.stderr and "Warning" not in result.stderr


@pytest.fixture(scope="module")
def stored(tmp_path_factory):
    """A tiny store of two frames, written in this process (no cluster)."""
    folder = tmp_path_factory.mktemp("stored")
    text = TINY_SWEEP.format(name="s", seed=2, realisations=2, output="s.zarr")
    plan = parse_sweep(text.replace("scene:\n", "scene:\n  sequence: {frames: 2}\n"))
    url = str(folder / "s.zarr")
    create_store(plan, Store(url))
    for _, jobs in task_batches(plan, range(plan.samples), shard_size(plan)):
        assert render_shard(Store(url), jobs) == []
    return url


def test_preview_renders_on_the_backend_and_device_chosen(tmp_path, monkeypatch):
    # issue #39 item 5: `preview --backend torch` renders the sweep's sample on torch (it
    # rendered on numpy only), as `run --backend torch` would write it: within the
    # backends' agreement (PEAK_TOLERANCE of each expected image's peak) of numpy's
    pytest.importorskip("torch")
    from test_render_batch import PEAK_TOLERANCE

    from workers.backends.backend import Backend

    torch_cpu = Backend(name="torch", device="cpu")
    sweep = tiny(tmp_path)
    rendered = []
    real = plots.render

    def spy(scene, *, seed, backend, device):
        rendered.append((backend, device))
        return real(scene, seed=seed, backend=backend, device=device)

    monkeypatch.setattr(plots, "render", spy)
    output = tmp_path / "p.png"
    assert main(["preview", str(sweep), "--backend", "torch", "--output", str(output)]) == 0
    assert rendered == [("torch", "cpu")] and output.stat().st_size > 0
    plan = load_sweep(sweep)
    on_torch = plots.render_preview(plan, 0, torch_cpu)
    on_numpy = plots.render_preview(plan, 0)
    a, b = on_numpy.expected.values.astype(np.float64), on_torch.expected.values
    peak = np.abs(a).max(axis=(-2, -1))
    assert peak.min() > 0
    assert (np.abs(a - b).max(axis=(-2, -1)) <= PEAK_TOLERANCE * peak).all()
    assert (on_numpy.target_mask.values == on_torch.target_mask.values).all()
    assert not np.array_equal(on_numpy.image.values, on_torch.image.values)  # torch's noise


@pytest.mark.parametrize(
    ("flags", "message"),
    [
        (["--device", "tpu"], "--device: 'tpu' is neither 'cpu' nor 'cuda'"),
        (["--backend", "numpy", "--device", "cuda"], "--device: the numpy backend runs on"),
        (
            ["--backend", "torch", "--point", "1"],
            "--backend torch: point 1 renders by Monte Carlo (transport.method: monte_carlo)",
        ),
    ],
    ids=["unknown-device", "numpy-on-cuda", "monte-carlo-on-torch"],
)
def test_preview_refuses_a_backend_that_cannot_render_its_sample(tmp_path, cli, flags, message):
    # issue #39 item 5: the flag named, exit 2, no traceback, nothing drawn
    sweep = tiny(tmp_path)
    sweep.write_text(
        sweep.read_text().replace(
            "target.shape: {values: [sphere, none]}",
            "transport.method: {values: [small_angle, monte_carlo]}",
        )
    )
    result = cli("preview", "t.yaml", "--output", "p.png", *flags, cwd=tmp_path)
    assert result.returncode == 2, result.stderr
    assert f"oceanlidar preview: error: {message}" in result.stderr
    assert "Traceback" not in result.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["t.yaml"]


def test_preview_of_a_store_refuses_a_backend(stored, tmp_path, cli):
    # a store's sample is read as it was rendered: a backend asked would be ignored
    for flags in (["--backend", "torch"], ["--device", "cpu"]):
        result = cli("preview", stored, "--output", "p.png", *flags, cwd=tmp_path)
        assert result.returncode == 2, result.stderr
        assert f"oceanlidar preview: error: {flags[0]}: preview reads a store's sample" in (
            result.stderr
        )
    assert list(tmp_path.iterdir()) == []


def test_preview_reads_a_store_and_shares_one_scale(stored, tmp_path, monkeypatch):
    drawn = []

    def spy(ds, **options):
        drawn.append((ds, options))
        return figure(ds, **options)

    figure = plots.preview_figure
    monkeypatch.setattr(plots, "preview_figure", spy)
    output = tmp_path / "p.gif"
    assert (
        main(["preview", stored, "--sample", "3", "--shared-scale", "--output", str(output)]) == 0
    )
    image = xr.open_zarr(stored)["image"][3].values
    assert [options["frame"] for _, options in drawn] == [0, 1]
    for ds, options in drawn:
        assert ds["image"].values.tobytes() == image.tobytes()
        # one scale for every gate and frame, clipped at the 99.5th percentile (issue #27)
        scales = np.asarray(options["scales"])
        assert (scales == scales[0]).all()
        assert scales[0, 0] == image.min()
        assert scales[0, 1] == pytest.approx(np.percentile(image.astype(float), 99.5))
        assert "point 1: target.shape=none; realisation 1" in options["title"]
    drawn.clear()
    assert (
        main(
            [
                "preview",
                stored,
                "--sample",
                "3",
                "--frame",
                "1",
                "--output",
                str(tmp_path / "a.png"),
            ]
        )
        == 0
    )
    assert [options["frame"] for _, options in drawn] == [1]
    own = np.percentile(image[1].astype(float), 99.5, axis=(1, 2))  # each gate's, this frame
    np.testing.assert_allclose(np.asarray(drawn[0][1]["scales"])[:, 1], own)
    shown = figure(drawn[0][0], frame=1, scales=[(0.0, 7.0)] * image.shape[1])
    assert all(ax.get_images()[0].get_clim() == (0.0, 7.0) for ax in shown.axes if ax.get_images())


@pytest.mark.parametrize(
    "flags, env, named",
    [
        (["--server", "not-a-url"], {}, "--server 'not-a-url'"),
        (["--server", "http://"], {}, "--server 'http://'"),
        ([], {"OCEANLIDAR_SERVER": "ftp://host/"}, "OCEANLIDAR_SERVER 'ftp://host/'"),
        ([], {"OCEANLIDAR_SERVER": "http://[::1"}, "OCEANLIDAR_SERVER 'http://[::1'"),
    ],
)
def test_a_server_that_is_no_http_url_is_refused(cli, tmp_path, flags, env, named):
    result = cli("status", *flags, "x", cwd=tmp_path, env=env)
    assert result.returncode == 2, result.stderr
    assert f"oceanlidar status: error: {named}: not an http:// or https:// URL" in result.stderr
    assert "Traceback" not in result.stderr


@pytest.mark.parametrize("command", ["schema", "info"])
def test_a_closed_stdout_ends_the_command_quietly(stored, tmp_path, command):
    """``oceanlidar info STORE | head -1``: no BrokenPipeError traceback, exit 1 (Python's
    convention for EPIPE)."""
    reader, writer = os.pipe()
    os.close(reader)  # the reader is gone before anything is written
    try:
        process = start_cli(
            command,
            *([stored] if command == "info" else []),
            cwd=tmp_path,
            stdout=writer,
            stderr=subprocess.PIPE,
        )
    finally:
        os.close(writer)
    _, err = process.communicate(timeout=120)
    assert process.returncode == 1 and err.decode() == ""


def test_jobs_of_an_unknown_state_are_refused(cli, tmp_path):
    result = cli("jobs", "--state", "bogus", cwd=tmp_path)
    assert result.returncode == 2
    assert "argument --state: invalid choice: 'bogus'" in result.stderr
    assert "queued" in result.stderr and "Traceback" not in result.stderr


def test_verbosity_flags_go_before_or_after_the_command(tmp_path, capsys):
    # issue #37 item 18: `validate x.yaml -q` was refused ("unrecognized arguments")
    assert main(["validate", str(tiny(tmp_path)), "--no-estimate", "-q"]) == 0
    for argv, verbose, quiet in [
        (["run", "x.yaml", "-q"], 0, 1),
        (["-q", "run", "x.yaml"], 0, 1),
        (["-v", "run", "x.yaml", "-qq"], 1, 2),
        (["-q", "info", "x.zarr", "-q"], 0, 1),  # given after, it replaces the count
        (["schema", "-vv"], 2, 0),
    ]:
        args = parser().parse_args(argv)
        assert (args.verbose, args.quiet) == (verbose, quiet), argv


@pytest.mark.parametrize(
    "argv, message",
    [
        (["run", "{sweep}", "--output", ""], "argument --output: must name a path or URL"),
        (["run", "{sweep}", "--output", " "], "argument --output: must name a path or URL"),
        (["run", "{sweep}", "--output", "a\nb.zarr"], "control characters are not allowed"),
        (["detect", "{sweep}", "--output", ""], "argument --output: must name a path or URL"),
        (["run", "{nul}"], "output: Value error, control characters are not allowed"),
        (["validate", "{nul}"], "output: Value error, control characters are not allowed"),
    ],
    ids=["run-empty", "run-blank", "run-newline", "detect-empty", "run-nul", "validate-nul"],
)
def test_an_output_that_names_nothing_is_refused(tmp_path, capsys, monkeypatch, argv, message):
    # issue #37 item 15: `--output ''` was ignored (the sweep's own output written) and
    # `output: "a\0b.zarr"` ended in a traceback (embedded null byte)
    monkeypatch.chdir(tmp_path)
    sweep = tiny(tmp_path)
    nul = tmp_path / "nul.yaml"
    nul.write_text(sweep.read_text().replace("output: t.zarr", 'output: "a\\0b.zarr"'))
    argv = [arg.format(sweep=sweep, nul=nul) for arg in argv]
    try:
        status = main(argv)
    except SystemExit as error:  # argparse's refusal
        status = error.code
    err = capsys.readouterr().err
    assert status == 2 and message in err and "Traceback" not in err, err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["nul.yaml", "t.yaml"]


def test_preview_picks_a_sample_by_point_and_realisation(stored, tmp_path, capsys, monkeypatch):
    # issue #37 item 19: a sample could be named by its index alone
    titles = []
    figure = plots.preview_figure
    monkeypatch.setattr(
        plots, "preview_figure", lambda ds, **k: titles.append(k["title"]) or figure(ds, **k)
    )
    picture = str(tmp_path / "p.png")
    assert (
        main(["preview", stored, "--point", "1", "--realisation", "1", "--output", picture]) == 0
    )
    assert "sample 3 (point 1: target.shape=none; realisation 1)" in titles[-1]
    assert main(["preview", stored, "--point", "1", "--output", picture, "--dpi", "30"]) == 0
    assert "sample 2 (point 1: target.shape=none; realisation 0)" in titles[-1]
    sweep = str(tiny(tmp_path))  # a sweep file's samples alike
    assert main(["preview", sweep, "--point", "1", "--realisation", "1", "--output", picture]) == 0
    assert "sample 3 (point 1: target.shape=none; realisation 1)" in titles[-1]
    for flags, message in [
        (["--point", "2"], "--point 2 --realisation 0: the sweep has points 0..1"),
        (["--point", "0", "--realisation", "2"], "realisations 0..1"),
        (["--realisation", "1"], "--realisation needs --point"),
        (["--dpi", "0"], "--dpi 0.0: give dots per inch"),
    ]:
        assert main(["preview", stored, *flags, "--output", picture]) == 2, flags
        assert message in capsys.readouterr().err, flags


def test_a_batch_memory_with_a_unit_is_refused_saying_the_unit(tmp_path, capsys, monkeypatch):
    # "10GiB" is the size a user means; the flag takes the number of GiB alone
    monkeypatch.chdir(tmp_path)
    tiny(tmp_path)
    with pytest.raises(SystemExit) as stop:
        main(["validate", "t.yaml", "--batch-memory", "10GiB"])
    assert stop.value.code == 2
    error = capsys.readouterr().err
    assert "--batch-memory: '10GiB' is not a number of GiB (write the number alone" in error
    assert sorted(p.name for p in tmp_path.iterdir()) == ["t.yaml"]


def test_a_store_whose_template_a_stopped_run_left_is_refused_on_resume_and_overwritten(
    tmp_path, capsys, monkeypatch
):
    # a run stopped while writing its template leaves the root group and some arrays'
    # metadata, but no consolidated metadata (xarray consolidates last): a resume said a
    # traceback, --overwrite refused to delete the arrays it did not find listed
    monkeypatch.chdir(tmp_path)
    tiny(tmp_path)
    assert main(["run", "t.yaml", "--workers", "1"]) == 0
    root = tmp_path / "t.zarr" / "zarr.json"
    metadata = json.loads(root.read_text())
    del metadata["consolidated_metadata"]
    root.write_text(json.dumps(metadata))
    capsys.readouterr()
    assert main(["run", "t.yaml", "--workers", "1", "--resume"]) == 2
    error = capsys.readouterr().err
    assert "template was not finished (a run stopped while writing it); start again with" in error
    assert main(["run", "t.yaml", "--workers", "1", "--overwrite"]) == 0
    assert xr.open_zarr(tmp_path / "t.zarr").completed.values.all()
