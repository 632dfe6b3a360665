"""The sweep service end to end on a dask LocalCluster: bytes, resume, CLI, README."""

import os
import re
import shlex
import signal
import subprocess
import textwrap
from pathlib import Path

import numpy as np
import pytest
import xarray as xr
import yaml
from conftest import (
    ROOT,
    ended,
    holding,
    on_cluster,
    ring_around,
    same_values,
    start_cli,
    store_lock,
    wait_for_shards,
)
from numpy.testing import assert_allclose

from service.cli import main
from service.cluster import HOLD_LIMIT, dask_client
from service.run import execute, task_batches
from service.store.location import Store
from service.store.template import create_store
from service.sweep import load_sweep, parse_sweep
from workers.dataset.labels import RING_FRACTION
from workers.render import render
from workers.settings.seeds import SampleSeed

SWEEP = """\
name: small
seed: 11
realisations: 3
output: small.zarr
scene:
  surface: {grid_size: 32, spacing: 0.1, allow_repeat: true}  # tiny: the sea repeats
  receiver: {pixels: 16, gates: [[2.0, 6.0], [5.0, 9.0]]}
  radiometry: {mode: normalised, white_plane_photons: 100}
store: {expected: true}
sweep:
  method: grid
  parameters:
    target.depth: {values: [3.0, 6.0]}
    target.shape: {values: [sphere, none]}
"""


def write(path, text=SWEEP):
    path.write_text(text)
    return path


def assert_same_store(a, b):
    x, y = xr.open_zarr(a), xr.open_zarr(b)
    assert set(x.variables) == set(y.variables)
    for name in x.variables:
        assert same_values(x[name].values, y[name].values), name
    assert x.attrs == y.attrs


@pytest.fixture(scope="module")
def two_worker_store(tmp_path_factory, session_cluster):
    folder = tmp_path_factory.mktemp("two")
    plan = load_sweep(write(folder / "sweep.yaml"))
    url = str(folder / "small.zarr")
    assert len(session_cluster.nthreads()) == 2
    with on_cluster(session_cluster):
        result = execute(
            plan, Store.at(url), workers=2, batch_size=2, progress_stream=open(os.devnull, "w")
        )
    assert result.written == plan.samples == 12 and not result.failed
    return plan, url


def test_samples_equal_render_of_the_same_scene_and_seed(two_worker_store):
    plan, url = two_worker_store
    ds = xr.open_zarr(url)
    assert ds["completed"].values.all()
    for sample in (0, 4, 11):
        point, realisation = divmod(sample, plan.realisations)
        alone = render(
            plan.scenes[point],
            seed=SampleSeed(root=plan.sweep.seed, point=point, realisation=realisation),
        )
        for name in alone.variables:
            stored = ds[name].isel(sample=sample) if "sample" in ds[name].dims else ds[name]
            assert stored.values.tobytes() == alone[name].values.tobytes(), name
            assert stored.dtype == alone[name].dtype, name
        assert int(ds["point"][sample]) == point and int(ds["realisation"][sample]) == realisation
        assert float(ds["target_depth"][sample]) == plan.points[point]["target.depth"]
        assert str(ds["target_shape"][sample].values) == plan.points[point]["target.shape"]


def test_one_and_two_workers_write_the_same_bytes(two_worker_store, tmp_path):
    plan, url = two_worker_store
    other = str(tmp_path / "small.zarr")  # same name: statistics record their store's name
    execute(plan, Store.at(other), workers=1, batch_size=3, progress_stream=open(os.devnull, "w"))
    assert_same_store(url, other)
    assert_same_store(Store(url).stats.url, Store(other).stats.url)


def test_store_metadata_and_statistics(two_worker_store):
    plan, url = two_worker_store
    ds = xr.open_zarr(url)
    assert ds.attrs["sweep"] == SWEEP and ds.attrs["sweep_sha256"] == plan.digest
    assert ds.attrs["Conventions"].startswith("CF-")
    # shards of two samples (the task's batch), one sample per chunk inside
    assert ds["image"].encoding["chunks"] == (1, 1, 2, 16, 16)
    assert ds["image"].encoding["shards"] == (2, 1, 2, 16, 16)
    assert ds["completed"].encoding["chunks"] == (2,)
    assert sorted(p.name for p in Path(url, "image").iterdir()) == [
        *(f"c.{k}.0.0.0.0" for k in range(6)),
        "zarr.json",
    ]
    for name, variable in ds.variables.items():
        assert "units" in variable.attrs and "long_name" in variable.attrs, name
    assert ds["target_depth"].attrs == {
        "long_name": "swept scene parameter target.depth",
        "units": "m",
        "parameter": "target.depth",
    }
    stats = xr.open_zarr(Store(url).stats.url)
    assert stats.sizes["point"] == 4 and stats.sizes["gate"] == 2
    assert stats["gate_top"].values.tolist() == [2.0, 5.0]
    # gates numbered from 1 in the samples and their statistics (issue #27)
    assert ds["gate"].values.tolist() == stats["gate"].values.tolist() == [1, 2]
    assert stats["samples"].values.tolist() == [3, 3, 3, 3]
    # the statistics equal a direct computation on the loaded store
    image = ds["image"].values
    assert np.allclose(stats["image_mean"].values[1], image[3:6].mean(axis=(0, 1)), rtol=1e-5)
    # sphere at 3 m: in gate 2–6 m, above gate 5–9 m (its shadow); at 6 m: in both gates
    visible = stats["visible_fraction"].values
    assert visible[0].tolist() == [1.0, 0.0] and visible[2].tolist() == [1.0, 1.0]
    contrast = stats["target_contrast"].values
    assert np.isnan(contrast[1]).all()  # no target, no contrast
    assert contrast[0, 0] > 0 and (contrast[2] > 0).all()  # the mine in a gate is bright
    assert contrast[0, 1] < 0  # and darkens the gate below it
    assert stats["target_contrast"].attrs["long_name"].startswith("mean over samples and frames")
    # Issue #24, item 7, from the stored images alone: the contrast is each sample's change
    # over its mask against its target-free twin (the next point, the same realisation: the
    # grid pairs target.shape sphere and none, as `detect` does), the CNR each sample's
    # (mask - ring) of the noisy image over the ring's standard deviation (undefined where
    # the ring is uniform, as a dim gate's zero counts are); both averaged over realisations
    expected, image = (ds[name].values[:, 0].astype(np.float64) for name in ("expected", "image"))
    masks = ds["target_mask"].values[:, 0].astype(bool)
    width = max(2, round(RING_FRACTION * masks.shape[-1]))
    for point in (0, 2):
        change, cnr = [], []
        for sample in range(point * 3, point * 3 + 3):
            mask, ring = masks[sample], ring_around(masks[sample], width)
            shown, bare = (
                expected[sample][:, mask].mean(axis=1),
                expected[sample + 3][:, mask].mean(axis=1),
            )
            change.append((shown - bare) / bare)
            background = image[sample][:, ring]
            spread = background.std(axis=1)
            difference = image[sample][:, mask].mean(axis=1) - background.mean(axis=1)
            cnr.append(np.where(spread > 0, difference / np.where(spread > 0, spread, 1), np.nan))
        assert_allclose(contrast[point], np.mean(change, axis=0), rtol=1e-5)
        assert_allclose(stats["cnr"].values[point], np.nanmean(cnr, axis=0), rtol=1e-5)


def test_bounded_submission_and_batches(tmp_path):
    plan = parse_sweep(SWEEP)
    # one task per shard of three samples, holding the shard's samples still to render
    batches = list(task_batches(plan, [0, 1, 2, 3, 5, 6, 7, 11], 3))
    assert [[job[0] for job in jobs] for _, jobs in batches] == [[0, 1, 2], [3, 5], [6, 7], [11]]
    url = str(tmp_path / "b.zarr")
    create_store(plan, Store(url), samples_per_shard=1)
    from service.run import run_plan

    with dask_client(workers=1, scheduler=None) as client:
        result = run_plan(plan, Store(url), client=client, progress_stream=open(os.devnull, "w"))
    assert result.written == 12 and result.max_in_flight <= 2


def test_a_run_on_a_client_that_is_not_the_default_one(tmp_path, shared_cluster):
    # execute(client=...) for a library user's own client: dask's `wait` looked up the
    # default client ("No clients found" when the given one is not the default)
    from distributed import default_client

    with pytest.raises(ValueError, match="No clients found"):
        default_client()
    plan = parse_sweep(SWEEP)
    result = execute(
        plan,
        Store.at(str(tmp_path / "own.zarr")),
        client=shared_cluster,
        progress_stream=open(os.devnull, "w"),
    )
    assert result.ok and result.written == plan.samples


def test_interrupted_run_resumes_to_the_same_store(tmp_path, cli, shared_cluster):
    # 48 samples, one a task: interrupted once 2 are written, the tasks held there (a
    # loaded machine could finish the run before a signal sent at a time). The run starts
    # with SIGINT at its default, as at a terminal (`start_cli`): started with it ignored,
    # as the suite's own processes had it when CI started the suite, the run went on
    # after the Ctrl-C, its held task waited out its limit, and the test timed out
    sweep = write(tmp_path / "sweep.yaml", SWEEP.replace("realisations: 3", "realisations: 12"))
    plan = load_sweep(sweep)
    url = str(tmp_path / "reference.zarr")
    execute(plan, Store.at(url), workers=1, batch_size=4, progress_stream=open(os.devnull, "w"))
    target = tmp_path / "interrupted.zarr"
    held = tmp_path / "held"
    process = start_cli(
        "run",
        sweep,
        "--output",
        target,
        "--workers",
        1,
        "--batch",
        1,
        cwd=tmp_path,
        env=holding(held, 2),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,  # its own process group, as a terminal's foreground job
    )
    try:
        wait_for_shards(held, 2, process)
        done = int(Store(str(target)).completed().sum())
    finally:
        os.killpg(process.pid, signal.SIGINT)  # a Ctrl-C reaches the workers too
    _, err = ended(process)
    assert 2 <= done, err
    assert "Traceback" not in err and "KeyboardInterrupt" not in err, err  # the workers' own
    assert "leaked semaphore" not in err, err
    partial = Store(str(target)).completed()
    assert process.returncode == 1 and "--resume" in err, err
    assert 0 < partial.sum() < plan.samples
    # the summary counts the tasks in flight at the signal that completed after it too
    assert f"wrote {partial.sum()} samples" in err, err
    again = cli(
        "run", str(sweep), "--output", str(target), "--resume", "--workers", "1", cwd=tmp_path
    )
    assert again.returncode == 0, again.stderr
    assert "already complete" in again.stderr
    assert_same_store(url, str(target))


def test_a_terminated_run_stops_as_interrupted_and_releases_its_lock(tmp_path):
    # SIGTERM (docker stop, kill, a batch system's time limit) as a Ctrl-C: by default the
    # process ended on the spot, silent, its writer's lock left in the store. Sent to the
    # process group, as a batch system does (issue #27): the workers died on it, cut off
    # mid-message (a traceback) and leaking their semaphores (the resource tracker warned)
    sweep = write(tmp_path / "sweep.yaml", SWEEP.replace("realisations: 3", "realisations: 12"))
    target = tmp_path / "terminated.zarr"
    command = ("run", sweep, "--output", target, "--workers", 2, "--batch", 1)
    held = tmp_path / "held"
    process = start_cli(
        *command,
        cwd=tmp_path,
        env=holding(held, 1),
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
    )
    try:
        wait_for_shards(held, 1, process)
    finally:
        os.killpg(process.pid, signal.SIGTERM)
    _, err = ended(process)
    assert process.returncode == 1 and "interrupted: run again with --resume" in err, err
    assert "leaked semaphore" not in err and "Traceback" not in err, err
    assert not store_lock(target).exists()
    assert 0 < Store(str(target)).completed().sum() < 48


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_an_interrupt_mid_render_abandons_the_task_and_leaks_nothing(tmp_path, sig):
    # A task still executing at the interrupt (a sample mid-render, in compiled code that
    # no cancel stops: a held task that is `busy`): its worker waited for it when asked to
    # close, its nanny killed it 4 s later, and the resource tracker warned of the blosc
    # lock it left ("leaked semaphore"). The worker now leaves the task and exits
    sweep = write(tmp_path / "sweep.yaml", SWEEP.replace("realisations: 3", "realisations: 12"))
    target = tmp_path / "abandoned.zarr"
    held = tmp_path / "held"
    process = start_cli(
        *("run", sweep, "--output", target, "--workers", 1, "--batch", 1),
        cwd=tmp_path,
        env=holding(held, 2, busy=True),
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
    )
    try:
        wait_for_shards(held, 2, process)
    finally:
        os.killpg(process.pid, sig)
    # the busy task goes on for HOLD_LIMIT (120 s): the run ends without it
    _, err = ended(process, timeout=HOLD_LIMIT / 2)
    assert process.returncode == 1 and "interrupted: run again with --resume" in err, err
    assert "leaked semaphore" not in err and "Traceback" not in err, err
    assert not store_lock(target).exists()
    assert 0 < Store(str(target)).completed().sum() < 48


def test_existing_output_is_refused_and_left_unchanged(two_worker_store, tmp_path, capsys):
    _, url = two_worker_store
    sweep = write(tmp_path / "sweep.yaml")
    before = {p: p.stat().st_mtime_ns for p in Path(url).rglob("*")}
    assert main(["run", str(sweep), "--output", url]) == 2
    assert "already exists" in capsys.readouterr().err
    other = write(tmp_path / "other.yaml", SWEEP.replace("seed: 11", "seed: 12"))
    assert main(["run", str(other), "--output", url, "--resume"]) == 2
    assert "different sweep" in capsys.readouterr().err
    assert before == {p: p.stat().st_mtime_ns for p in Path(url).rglob("*")}


@pytest.mark.parametrize(
    ("text", "fragment"),
    [
        (SWEEP.replace("realisations: 3", "realisations: 3\nflavour: x"), "flavour"),
        (SWEEP.replace("seed: 11", "seed: eleven"), "seed"),
        (
            SWEEP.replace("target.depth: {values: [3.0, 6.0]}", "target.depth: {values: [-1]}"),
            "scene.target.depth",
        ),
        (SWEEP.replace("target.depth", "target.deepness"), "target.deepness"),
        (
            SWEEP.replace("output: small.zarr", "output: small.zarr\nx: !!python/name:os.system"),
            "plain YAML",
        ),
        ("\x00\x01binary", "not YAML"),
        (SWEEP.replace("[3.0, 6.0]", "!!set {3.0, 6.0}"), "line 13: YAML sets"),
        (
            SWEEP.replace(
                "scene:\n", "scene:\n  sequence: {frames: 2, velocity: [1e308, 0, 0]}\n"
            ),
            "scene.sequence.velocity: the platform would fly",
        ),
        (SWEEP + "seed: 12\n", "line 15: duplicate key 'seed' (first on line 2)"),
    ],
    ids=[
        "unknown-key",
        "wrong-type",
        "out-of-range",
        "unknown-path",
        "python-tag",
        "binary",
        "set",
        "velocity-1e308",
        "duplicate-key",
    ],
)
def test_cli_bad_input_exits_2_with_a_message_and_writes_nothing(tmp_path, text, fragment, cli):
    sweep = tmp_path / "bad.yaml"
    sweep.write_text(text)
    result = cli("run", str(sweep), cwd=tmp_path)
    assert result.returncode == 2
    assert fragment in result.stderr and "Traceback" not in result.stderr
    assert not (tmp_path / "small.zarr").exists()


def test_cli_refuses_oversized_sweeps_unless_told(tmp_path, capsys):
    big = SWEEP.replace("realisations: 3", "realisations: 300000")
    sweep = write(tmp_path / "big.yaml", big)
    assert main(["validate", str(sweep)]) == 2
    assert "--no-limits" in capsys.readouterr().err
    assert main(["validate", str(sweep), "--no-limits"]) == 0
    assert "1200000 samples" in capsys.readouterr().out


def test_cli_validate_info_and_stats(two_worker_store, tmp_path, capsys):
    _, url = two_worker_store
    assert main(["validate", str(write(tmp_path / "s.yaml"))]) == 0
    out = capsys.readouterr().out
    assert "4 parameter points x 3 realisations = 12 samples" in out
    assert main(["info", url]) == 0
    out = capsys.readouterr().out
    assert "12/12 complete" in out and "target.depth" in out
    assert main(["stats", url]) == 0
    assert main(["info", str(tmp_path / "nothing.zarr")]) == 2
    assert "no store there" in capsys.readouterr().err


def test_readme_training_example_runs(tmp_path, monkeypatch, shared_cluster):
    readme = (ROOT / "README.md").read_text()
    code = re.search(
        r"Reading a store for analysis and for training:\n\n```python\n(.*?)```", readme, re.S
    ).group(1)
    sweep = tmp_path / "quick.yaml"
    sweep.write_text(
        SWEEP.replace("name: small", "name: quickstart")
        .replace("[3.0, 6.0]", "[3.0, 8.0]")
        .replace("output: small.zarr", "output: quickstart.zarr")
    )
    monkeypatch.chdir(tmp_path)
    assert main(["run", str(sweep), "--workers", "1"]) == 0
    exec(compile(code, "README.md", "exec"), {})


FENCE = re.compile(r"^ {0,3}(`{3,}|~{3,})\s*([^`\s]*)")


def code_blocks(text):
    """CommonMark fenced blocks: (first line, last line or None if never closed, language,
    lines)."""
    blocks, opened = [], None
    for number, line in enumerate(text.splitlines(), 1):
        fence = FENCE.match(line)
        if opened is None:
            if fence:
                opened = (number, fence.group(1), fence.group(2), [])
            continue
        start, marker, language, lines = opened
        closing = fence and fence.group(1)[0] == marker[0] and len(fence.group(1)) >= len(marker)
        if closing and not fence.group(2) and line.strip() == fence.group(1):
            blocks.append((start, number, language, lines))
            opened = None
        else:
            lines.append(line)
    if opened is not None:
        blocks.append((opened[0], None, opened[2], opened[3]))
    return blocks


def test_readme_fences_close_and_swallow_no_section():
    readme = (ROOT / "README.md").read_text()
    blocks = code_blocks(readme)
    assert len(blocks) >= 7
    for start, end, language, lines in blocks:
        assert end is not None, f"README line {start}: a code fence that never closes"
        # in code whose comments start with "#", only "##" and deeper read as headings
        heading = r"#{2,6} \S" if language in ("python", "bash", "yaml") else r"#{1,6} \S"
        swallowed = [line for line in lines if re.match(heading, line)]
        assert not swallowed, f"README line {start}: a code block swallows {swallowed}"
        if language == "yaml":  # prose swallowed by a block is not YAML
            yaml.safe_load(textwrap.dedent("\n".join(lines)))
        if language == "python":
            compile("\n".join(lines), f"README.md line {start}", "exec")
    code = {number for start, end, _, _ in blocks for number in range(start, end + 1)}
    headings = [
        line
        for number, line in enumerate(readme.splitlines(), 1)
        if number not in code and line.startswith("#")
    ]
    assert {"### The sweep file", "### The dataset", "## Layout"} <= set(headings)


def test_a_swallowing_fence_is_caught():
    broken = "intro\n\n```yaml\na: 1\n```yaml\n\n### The dataset\n\ntext\n```\n"
    ((start, end, _, lines),) = code_blocks(broken)
    assert (start, end) == (3, 10) and "### The dataset" in lines
    assert code_blocks("```bash\nls\n")[0][1] is None


def test_overwrite_never_deletes_what_is_not_a_store(tmp_path, capsys):
    victim = tmp_path / "thesis"
    (victim / "chapter").mkdir(parents=True)
    (victim / "chapter" / "one.tex").write_text("precious")
    sweep = write(tmp_path / "s.yaml")
    assert main(["run", str(sweep), "--output", str(victim), "--overwrite"]) == 2
    assert "not an oceanlidar samples store" in capsys.readouterr().err
    assert (victim / "chapter" / "one.tex").read_text() == "precious"
    assert main(["run", str(sweep), "--output", str(victim), "--resume"]) == 2
    assert "not an oceanlidar samples store" in capsys.readouterr().err


def test_list_valued_parameters_become_string_coordinates(tmp_path):
    plan = parse_sweep(
        SWEEP.replace(
            "    target.shape: {values: [sphere, none]}",
            "    sequence.velocity: {values: [[0, 0, 0], [1, 0, 0]]}",
        )
    )
    url = str(tmp_path / "v.zarr")
    create_store(plan, Store(url))
    ds = xr.open_zarr(url)
    assert ds["sequence_velocity"].values[0] == "[0, 0, 0]"
    assert ds["sequence_velocity"].values[-1] == "[1, 0, 0]"


@pytest.mark.parametrize("options", ["[1]", "not json"], ids=["array", "garbage"])
def test_storage_options_must_be_a_json_object(tmp_path, options, cli):
    result = cli("validate", str(write(tmp_path / "s.yaml")), cwd=tmp_path)
    assert result.returncode == 0
    result = cli("info", str(tmp_path / "x.zarr"), "--storage-options", options, cwd=tmp_path)
    assert result.returncode == 2 and "storage-options" in result.stderr
    assert "Traceback" not in result.stderr


def test_the_embedded_cluster_listens_on_loopback_only():
    import psutil

    me = psutil.Process()

    def listening():
        return {
            (process.pid, connection.laddr)
            for process in [me, *me.children(recursive=True)]
            for connection in process.net_connections(kind="inet")
            if connection.status == psutil.CONN_LISTEN
        }

    before = listening()
    with dask_client(workers=2, scheduler=None):
        opened = listening() - before
    assert opened, "the cluster should listen somewhere"
    assert {address.ip for _, address in opened} == {"127.0.0.1"}


def test_a_scene_that_cannot_be_rendered_is_refused_once_with_its_parameters(tmp_path, cli):
    """A singular kriging system is the input's error: reported per sample, never retried."""
    near = "[[1.0, 2.0, 0.1], [1.000001, 2.0, 0.1]]"
    text = SWEEP.replace(
        "allow_repeat: true}", f"allow_repeat: true, conditioning: {{points: {near}}}}}"
    )
    sweep = write(tmp_path / "singular.yaml", text)
    result = cli("run", sweep, "--workers", 1, "--batch", 3, cwd=tmp_path)
    assert result.returncode == 1, result.stderr
    err = result.stderr
    reason = "12 samples refused (bad input, not retried): surface.conditioning.points: "
    assert err.count(reason) == 1 and "ill-conditioned" in err
    refused = re.findall(r"^  sample (\d+) \(point \d: (.*)\)$", err, re.M)
    assert [int(sample) for sample, _ in refused] == list(range(12))
    assert refused[4][1] == "target.depth=3.0, target.shape='none'; realisation 1"
    assert " failed: " not in err
    assert "Traceback" not in result.stderr


def test_readme_commands_read_only_stores_that_earlier_ones_make():
    # issue #37 item 18: "Using it" listed `detect detection-study.zarr` with no `run`
    # making it, and the SweepStream example named "detection-study.yaml" (under configs/)
    readme = (ROOT / "README.md").read_text()
    start, _, _, lines = next(
        block
        for block in code_blocks(readme)
        if readme.splitlines()[block[0] - 3] == "## Using it"
    )
    made = set()
    for line in lines:
        words = shlex.split(line.split("#")[0])
        if words[:2] == ["oceanlidar", "run"]:
            made.add(yaml.safe_load((ROOT / words[2]).read_text())["output"])
        elif words[:2] == ["oceanlidar", "detect"]:
            assert words[2] in made, line
            made.add(words[2].removesuffix(".zarr") + ".detect.zarr")
        elif words[:1] == ["oceanlidar"] and words[1] in ("info", "stats", "plot", "preview"):
            assert not words[2].endswith(".zarr") or words[2] in made, line
    assert {"detection-study.zarr", "detection-study.detect.zarr"} <= made
    for start, _, language, lines in code_blocks(readme):
        if language == "python":
            for path in re.findall(r"\"([\w/.-]+\.yaml)\"", "\n".join(lines)):
                assert (ROOT / path).is_file(), f"README line {start}: no file {path}"
