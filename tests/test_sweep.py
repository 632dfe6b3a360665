"""Sweep files: schema, safe loading, expansion, seeds and plans."""

import copy
import math
import os
import subprocess
import sys
import textwrap
import tracemalloc
import typing

import annotated_types
import numpy as np
import pytest
import xarray as xr
import yaml
from conftest import cli_command, run_cli
from pydantic import BaseModel

from service.errors import InputError
from service.points import assign
from service.store import template
from service.store.location import Store
from service.store.template import create_store
from service.sweep import load_sweep, memory_estimate, parse_sweep
from workers.backends.caches import clear_all
from workers.render import render
from workers.settings.scene import Scene

BASE = """\
name: t
seed: 3
realisations: 2
output: out.zarr
scene:
  receiver: {pixels: 16}
  surface: {grid_size: 32, spacing: 0.1, allow_repeat: true}  # tiny: the sea repeats
"""


def replaced(text, old, new):
    """`text` with `old` replaced by `new`; `old` must be there (no silent no-op edit)."""
    assert old in text, old
    return text.replace(old, new)


def sweep(extra=""):
    return parse_sweep(BASE + textwrap.dedent(extra))


def test_grid_expands_the_cartesian_product_in_file_order():
    plan = sweep(
        """
        sweep:
          method: grid
          parameters:
            target.depth: {values: [3.0, 5.0]}
            target.shape: {values: [sphere, none]}
        """
    )
    assert plan.points == (
        {"target.depth": 3.0, "target.shape": "sphere"},
        {"target.depth": 3.0, "target.shape": "none"},
        {"target.depth": 5.0, "target.shape": "sphere"},
        {"target.depth": 5.0, "target.shape": "none"},
    )
    assert plan.samples == 8
    assert plan.scenes[2].target.depth == 5.0 and plan.scenes[2].receiver.pixels == 16
    assert all(isinstance(s, Scene) for s in plan.scenes)


def test_zip_pairs_values_and_broadcasts_single_values():
    plan = sweep(
        """
        sweep:
          method: zip
          parameters:
            target.depth: {values: [3.0, 5.0, 7.0]}
            platform.altitude: {values: [20.0, 30.0, 40.0]}
            water.preset: {value: turbid_harbour}
        """
    )
    assert [p["platform.altitude"] for p in plan.points] == [20.0, 30.0, 40.0]
    assert {p["water.preset"] for p in plan.points} == {"turbid_harbour"}


def test_random_draws_are_reproducible_and_within_bounds():
    text = """
        sweep:
          method: random
          count: 50
          parameters:
            target.depth: {distribution: uniform, min: 2.0, max: 8.0}
            platform.altitude: {distribution: log_uniform, min: 20.0, max: 200.0}
            receiver.pixels: {distribution: int_uniform, min: 16, max: 24}
            target.shape: {values: [sphere, none]}
        """
    a, b = sweep(text), sweep(text)
    assert a.points == b.points and a.digest == b.digest
    depths = [p["target.depth"] for p in a.points]
    assert all(2.0 <= d <= 8.0 for d in depths) and len(set(depths)) == 50
    assert {p["target.shape"] for p in a.points} == {"sphere", "none"}
    assert {p["receiver.pixels"] for p in a.points} <= set(range(16, 25))


def test_digest_ignores_the_output_location_but_not_the_physics():
    a = sweep()
    b = parse_sweep(BASE.replace("out.zarr", "elsewhere.zarr"))
    c = parse_sweep(BASE.replace("seed: 3", "seed: 4"))
    assert a.digest == b.digest != c.digest


def test_size_limits_name_the_number_and_the_way_out():
    plan = sweep(
        """
        sweep:
          parameters:
            target.depth: {values: [1.0, 2.0, 3.0]}
        """
    )
    with pytest.raises(InputError, match=r"6 samples, over the limit of 5.*--no-limits"):
        plan.check_limits(max_samples=5)
    with pytest.raises(InputError, match="would store about"):
        plan.check_limits(max_bytes=1000)
    plan.check_limits()


@pytest.mark.parametrize(
    ("text", "message"),
    [
        (BASE + "colour: red\n", r"colour: Extra inputs are not permitted"),
        (BASE.replace("seed: 3", "seed: three"), r"seed: Input should be a valid integer"),
        (BASE.replace("realisations: 2", "realisations: 0"), r"realisations: .*greater than"),
        (BASE + "  target: {reflectance: 1.5}\n", r"scene\.target\.reflectance: .*less than"),
        (BASE + "  target: {depth: deep}\n", r"scene\.target\.depth: .*valid number"),
        (
            BASE + "sweep:\n  parameters:\n    target.colour: {values: [1]}\n",
            r"sweep\.parameters\.target\.colour: unknown path; target has",
        ),
        (
            BASE + "sweep:\n  parameters:\n    target: {values: [1]}\n",
            r"sweep\.parameters\.target: names a section",
        ),
        (
            BASE + "sweep:\n  parameters:\n    target.depth: {values: []}\n",
            r"values: List should have at least 1 item",
        ),
        (
            BASE + "sweep:\n  parameters:\n    target.depth: {values: [5.0, 0.1]}\n",
            r"parameter point 1 \(target\.depth=0\.1\):\nscene\.target",
        ),
        (
            BASE + "sweep:\n  parameters:\n    target.depth: {values: [5, 6.0, 5.0]}\n",
            r"^sweep\.parameters\.target\.depth\.values: 5\.0 is listed twice",
        ),
        (
            BASE + "sweep:\n  method: random\n  parameters:\n    target.depth: {values: [1.0]}\n",
            r"method random needs a count",
        ),
        (
            BASE
            + "sweep:\n  parameters:\n    target.depth: {distribution: uniform, min: 1, max: 2}\n",
            r"distributions need method random",
        ),
        (BASE + "extra: !!python/object/apply:os.system ['true']\n", r"not allowed|plain YAML"),
        ("a: [1, 2\n", r"not valid YAML"),
        ("- just\n- a list\n", r"must be a YAML mapping"),
        ("", r"must be a YAML mapping"),
        ("x:\n" + "".join("  " * i + "- \n" for i in range(1, 40)), r"nests deeper"),
        (BASE.replace("seed: 3", "seed: true"), r"^seed: expected a number, got a boolean"),
        (BASE.replace("seed: 3", 'seed: "3"'), r"^seed: expected a number, got a string"),
        (BASE + "  target: {depth: yes}\n", r"scene\.target\.depth: expected a number"),
        (
            BASE + "sweep:\n  parameters:\n    target.depth: {values: [3.0, true]}\n",
            r"parameter point 1 .*\nscene\.target\.depth: expected a number, got a boolean",
        ),
        (
            BASE + "sweep:\n  parameters:\n    target.depth: {values: !!set {3.0, 5.0}}\n",
            r"line 10: YAML sets \(!!set\) are not accepted",
        ),
        (BASE + "realisations: 5\n", r"line 8: duplicate key 'realisations' \(first on line 3\)"),
        (BASE + "  receiver: {pixels: 8}\n", r"line 8: duplicate key 'receiver' .*line 6"),
        (BASE + "loop: &a [1, *a]\n", r"line 8: the alias \*a .* self-referential"),
        (BASE + "loop: &a {b: {c: *a}}\n", r"self-referential"),
        (BASE + "  sequence: {velocity: [.nan, 0, 0]}\n", r"velocity\.0: must be a finite"),
        (BASE + "  sequence: {velocity: [0, -.inf, 0]}\n", r"velocity\.1: must be a finite"),
        (
            BASE + "  sequence: {frames: 3, velocity: [1e308, 0, 0]}\n",
            r"scene\.sequence\.velocity: the platform would fly 2e\+307 m",
        ),
    ],
    ids=[
        "unknown-key",
        "wrong-type",
        "out-of-range-realisations",
        "out-of-range-scene-value",
        "wrong-type-scene-value",
        "unknown-dotted-path",
        "path-to-a-section",
        "empty-values",
        "invalid-expanded-point",
        "repeated-grid-value",
        "random-without-count",
        "distribution-on-grid",
        "python-tag",
        "broken-yaml",
        "not-a-mapping",
        "empty-file",
        "deeply-nested",
        "bool-for-int",
        "string-for-int",
        "bool-for-float",
        "bool-in-values",
        "set",
        "duplicate-key",
        "duplicate-section",
        "self-alias-list",
        "self-alias-map",
        "velocity-nan",
        "velocity-inf",
        "velocity-1e308",
    ],
)
def test_bad_sweeps_say_where_and_why(text, message):
    with pytest.raises(InputError, match=message):
        parse_sweep(text)


def test_alias_bomb_is_refused_before_it_expands():
    lines = ['a: &a ["lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol"]']
    for i in range(1, 9):
        refs = ", ".join([f"*{chr(96 + i)}"] * 9)
        lines.append(f"{chr(97 + i)}: &{chr(97 + i)} [{refs}]")
    with pytest.raises(InputError, match="expands to more than"):
        parse_sweep("\n".join(lines) + "\n")


def test_files_that_are_not_yaml_text(tmp_path):
    binary = tmp_path / "image.png"
    binary.write_bytes(b"\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR\xff\xfe")
    with pytest.raises(InputError, match=r"not a UTF-8 text file|NUL"):
        load_sweep(binary)
    with pytest.raises(InputError, match="No such file"):
        load_sweep(tmp_path / "missing.yaml")
    huge = tmp_path / "huge.yaml"
    huge.write_text("a: " + "x" * 2_000_000)
    with pytest.raises(InputError, match="larger than"):
        load_sweep(huge)


def test_oversized_grid_is_refused_before_expansion():
    params = "".join(
        f"    target.{name}: {{values: {list(range(1, 60))}}}\n"
        for name in ("depth", "radius", "reflectance", "x", "y")
    )
    with pytest.raises(InputError, match="points"):
        parse_sweep(BASE + "sweep:\n  parameters:\n" + params)


def test_digest_follows_the_order_of_the_parameters():
    first = "    target.depth: {values: [3.0, 5.0]}\n    target.shape: {values: [sphere, none]}\n"
    second = "    target.shape: {values: [sphere, none]}\n    target.depth: {values: [3.0, 5.0]}\n"
    a = parse_sweep(BASE + "sweep:\n  parameters:\n" + first)
    b = parse_sweep(BASE + "sweep:\n  parameters:\n" + second)
    assert a.points != b.points and a.digest != b.digest


@pytest.mark.parametrize(
    ("spec", "message"),
    [
        ("{distribution: int_uniform, min: 16.5, max: 16.7}", "integer between"),
        ("{distribution: uniform, min: -1e308, max: 1e308}", "finite"),
        ("{distribution: normal, mu: 1, sigma: 1, min: 0}", "not min and max"),
        ("{distribution: uniform, min: 1, max: 2, sigma: 1}", "takes min and max"),
    ],
    ids=["no-integer", "overflow", "normal-with-min", "uniform-with-sigma"],
)
def test_distribution_parameters_are_checked(spec, message):
    text = (
        BASE + f"sweep:\n  method: random\n  count: 3\n  parameters:\n    target.depth: {spec}\n"
    )
    with pytest.raises(InputError, match=message):
        parse_sweep(text)


def test_exponents_without_a_dot_are_numbers():
    plan = parse_sweep(BASE.replace("spacing: 0.1", "spacing: 1e-1"))
    assert plan.scenes[0].surface.spacing == 0.1


def conditioned(folder, name):
    path = folder / "sweep.yaml"
    path.write_text(
        replaced(
            BASE, "allow_repeat: true}", f"allow_repeat: true, conditioning: {{file: {name}}}}}"
        )
    )
    return path


@pytest.mark.parametrize("role", ["sweep", "measurements"])
def test_inputs_must_be_regular_files(tmp_path, role):
    (tmp_path / "zero.yaml").symlink_to("/dev/zero")
    os.mkfifo(tmp_path / "fifo.yaml")
    for name in ("zero.yaml", "fifo.yaml"):
        sweep = conditioned(tmp_path, name) if role == "measurements" else tmp_path / name
        if name == "zero.yaml":  # a measurement link to /dev/zero also leads out of the folder
            refused = "not a regular file" if role == "sweep" else "leads out of the sweep"
            with pytest.raises(InputError, match=refused):
                load_sweep(sweep)
            continue
        # a FIFO blocks whoever opens it for reading: a process of its own, and a timeout
        result = run_cli("validate", sweep, cwd=tmp_path, timeout=60)
        assert result.returncode == 2 and "not a regular file" in result.stderr, result.stderr


@pytest.mark.parametrize("role", ["sweep", "measurements"])
def test_a_folder_is_no_input_file(tmp_path, role):
    # os.fdopen of a folder raised IsADirectoryError: a traceback (issue #26 item 11)
    (tmp_path / "folder.yaml").mkdir()
    sweep = conditioned(tmp_path, "folder.yaml") if role == "measurements" else tmp_path
    sweep = sweep / "folder.yaml" if role == "sweep" else sweep
    with pytest.raises(InputError, match=r"(folder\.yaml|file: .*): not a regular file"):
        load_sweep(sweep)


def test_a_huge_file_is_refused_after_reading_the_limit(tmp_path):
    huge = tmp_path / "huge.yaml"
    huge.touch()
    os.truncate(huge, 300_000_000)  # sparse: costs no disk
    # a fresh interpreter whose only child is the CLI, to measure the CLI's peak memory
    probe = (
        "import resource, subprocess, sys; "
        "r = subprocess.run(sys.argv[1:], capture_output=True, text=True); "
        "print(r.returncode, resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss); "
        "print(r.stderr, file=sys.stderr)"
    )
    command, env = cli_command("validate", huge)
    result = subprocess.run(
        [sys.executable, "-c", probe, *command], capture_output=True, text=True, env=env
    )
    code, peak_kib = map(int, result.stdout.split())
    assert code == 2 and "larger than 1,000,000 bytes" in result.stderr, result.stderr
    assert peak_kib < 300 * 1024  # the whole file would cost twice its size


@pytest.mark.parametrize(
    ("name", "message"),
    [
        ("/etc/passwd", "in the sweep file's folder or below it"),
        ("../elsewhere/points.csv", "in the sweep file's folder or below it"),
        ("secret.csv", "must start with the header line"),
        ("link.csv", "leads out of the sweep file's folder"),
    ],
    ids=["absolute", "parent", "not-csv", "link-out"],
)
def test_measurement_files_stay_beside_the_sweep_and_are_never_echoed(tmp_path, name, message):
    (tmp_path / "secret.csv").write_text("root:hunter2:0:0\nmore:secret\n")
    outside = tmp_path.parent / f"{tmp_path.name}-outside.csv"
    outside.write_text("x,y,elevation\n0.5,0.5,0.1\n")
    (tmp_path / "link.csv").symlink_to(outside)  # a valid file, but not the folder's
    with pytest.raises(InputError, match=message) as error:
        load_sweep(conditioned(tmp_path, name))
    assert "hunter2" not in str(error.value) and "root:" not in str(error.value)


def test_echoed_values_are_capped(tmp_path, capsys):
    from service.cli import main

    huge = "x" * 600_000
    with pytest.raises(InputError) as error:
        parse_sweep(BASE + f"sweep:\n  parameters:\n    target.shape: {{values: [{huge}]}}\n")
    assert "600,002 characters" in str(error.value) and len(str(error.value)) < 1000
    # a key is echoed as the place of the error: cut too
    sweep = tmp_path / "key.yaml"
    key = f"? target.{huge}\n    : {{values: [1]}}\n"  # explicit: YAML caps implicit keys
    sweep.write_text(BASE + "sweep:\n  parameters:\n    " + key)
    assert main(["validate", str(sweep)]) == 2
    err = capsys.readouterr().err
    assert "sweep.parameters.target.xxxx" in err and "(cut)" in err and len(err) < 2000


def test_memory_is_estimated_before_anything_is_built(tmp_path, capsys):
    from service.cli import main

    frames = BASE.replace("pixels: 16}", "pixels: 1024}\n  sequence: {frames: 64}")
    with pytest.raises(InputError, match=r"would need about .* GiB .* limit of 4\.00 GiB"):
        parse_sweep(frames)
    assert parse_sweep(frames, max_memory=None).scenes[0].receiver.pixels == 1024
    # 24 measurement times on a 2048² grid: the kriging system alone, refused unbuilt
    points = [[0.1 * i, 0.1, 0.0, 0.1 * i] for i in range(1, 25)]
    measured = replaced(
        replaced(BASE, "spacing: 0.1, ", "spacing: 0.01, "),
        "allow_repeat: true}",
        f"allow_repeat: true, conditioning: {{points: {points}}}}}",
    ).replace("grid_size: 32", "grid_size: 2048")
    with pytest.raises(InputError, match="would need about"):
        parse_sweep(measured)
    sweep = tmp_path / "frames.yaml"
    sweep.write_text(frames)
    assert main(["validate", str(sweep)]) == 2
    assert "--max-memory" in capsys.readouterr().err
    assert main(["validate", str(sweep), "--max-memory", "400", "--no-estimate"]) == 0
    # preview names the same remedy, and takes the flags it names
    picture = str(tmp_path / "p.png")
    assert main(["preview", str(sweep), "--output", picture]) == 2
    assert "pass --max-memory GIB or --no-limits" in capsys.readouterr().err

    class RenderedError(Exception):
        pass

    def rendered(plan, sample, backend):  # preview renders on --backend/--device
        raise RenderedError

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr("service.plots.render_preview", rendered)
        for flags in (["--max-memory", "400"], ["--no-limits"]):
            with pytest.raises(RenderedError):  # admitted: the render was reached
                main(["preview", str(sweep), *flags, "--output", picture])


@pytest.mark.parametrize(
    "sections",
    [
        {"receiver": {"pixels": 16, "gates": [[2.0, 6.0]]}, "surface": {"grid_size": 32}},
        {"receiver": {"pixels": 48}},
        {"receiver": {"pixels": 24}, "sequence": {"frames": 3, "interval": 0.05}},
        {
            "receiver": {"pixels": 32, "gates": [[0.5, 10.0]]},
            "sequence": {"frames": 4, "interval": 0.2, "velocity": [0.0, 0.0, 10.0]},
            "surface": {"allow_repeat": True},
        },
        {
            "receiver": {"pixels": 24},
            "surface": {"grid_size": 64, "conditioning": {"points": [[0.5, 0.5, 0.1]]}},
        },
        {
            "platform": {"nadir_deg": 25.0, "altitude": 60.0},
            "receiver": {"pixels": 40},
            "target": {"shape": "disk", "radius": 3.0},
            "surface": {"allow_repeat": True},
        },
        {"receiver": {"pixels": 16}, "laser": {"rays": 512}},
        {
            "receiver": {"pixels": 64},
            "surface": {"spectrum": "flat"},
            "transport": {"method": "monte_carlo", "photons": 20_000, "batches": 256},
        },
    ],
    ids=[
        "one-gate",
        "mldc",
        "frames",
        "climbing",
        "conditioned",
        "oblique-high",
        "laser-rays",
        "monte-carlo-batches",
    ],
)
def test_the_memory_estimate_bounds_the_render_from_above(sections):
    # peak allocations of a first sample (every cache empty), traced: the estimate must
    # hold it, and stay within 8x of it (a bound that refuses nothing is no bound)
    render(Scene.model_validate({"receiver": {"pixels": 8}}), seed=0)  # a process's once
    scene = Scene.model_validate(sections)
    estimate = memory_estimate(scene.model_dump(mode="json"))
    clear_all()
    tracemalloc.start()
    try:
        render(scene, seed=1)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak <= estimate <= 8 * peak, (peak / 2**20, estimate / 2**20)


def test_the_store_carries_every_swept_fields_unit(tmp_path):
    """The seven fields whose unit the store once gave as 1 (units were read from prose)."""
    expected = {
        "target.x": "m",
        "target.y": "m",
        "surface.max_elevation": "m",
        "water.theta0": "rad",
        "platform.azimuth_deg": "degree",
        "receiver.field_of_view_deg": "degree",
        "laser.field_of_view_deg": "degree",
        "target.depth": "m",
        "water.absorption": "1/m",
        "sequence.interval": "s",
        "surface.grid_size": "1",
    }
    values = {
        "target.x": [0.5, 1.0],
        "target.y": [0.5, 1.0],
        "surface.max_elevation": [0.1, 0.2],
        "water.theta0": [0.1, 0.12],
        "platform.azimuth_deg": [0.0, 10.0],
        "receiver.field_of_view_deg": [6.0, 6.7],
        "laser.field_of_view_deg": [6.0, 6.7],
        "target.depth": [3.0, 4.0],
        "water.absorption": [0.1, 0.2],
        "sequence.interval": [0.1, 0.2],
        "surface.grid_size": [32, 32],
    }
    lines = "".join(f"    {path}: {{values: {v}}}\n" for path, v in values.items())
    plan = parse_sweep(BASE + "sweep:\n  method: zip\n  parameters:\n" + lines)
    url = str(tmp_path / "units.zarr")
    create_store(plan, Store(url))
    ds = xr.open_zarr(url)
    names = {path: name for name, path in template.swept_parameters(ds).items()}
    assert {path: ds[names[path]].attrs["units"] for path in expected} == expected


DESIGN = """
    sweep:
      method: {method}
      count: {count}
      parameters:
        target.depth: {{distribution: uniform, min: 2.0, max: 10.0}}
        water.theta0: {{distribution: uniform, min: 0.05, max: 0.15}}
        target.radius: {{value: 0.2}}
        target.shape: {{values: [sphere, disk]}}
"""


def design(method, count, seed=3):
    text = BASE + textwrap.dedent(DESIGN.format(method=method, count=count))
    plan = parse_sweep(replaced(text, "seed: 3", f"seed: {seed}"))
    depth = np.array([point["target.depth"] for point in plan.points])
    theta0 = np.array([point["water.theta0"] for point in plan.points])
    return plan, (depth - 2.0) / 8.0, (theta0 - 0.05) / 0.1


@pytest.mark.parametrize("method", ["latin_hypercube", "sobol"])
def test_space_filling_designs_stratify_every_parameter(method):
    count = 16
    plan, depth, theta0 = design(method, count)
    assert len(plan.points) == count
    for u in (depth, theta0):  # one point in each of the count equal strata, per parameter
        assert sorted(np.floor(u * count).astype(int)) == list(range(count))
    assert {point["target.radius"] for point in plan.points} == {0.2}
    shapes = [point["target.shape"] for point in plan.points]
    assert shapes.count("sphere") == shapes.count("disk") == count // 2
    again, _, _ = design(method, count)
    assert again.points == plan.points and again.digest == plan.digest
    other, _, _ = design(method, count, seed=4)
    assert other.points != plan.points


def test_sobol_points_form_a_net_over_two_parameters():
    # the first two Sobol dimensions are a (0, 4, 2)-net in base 2 (scrambling keeps it):
    # every elementary box 2^-a x 2^-(4 - a) holds exactly one of the 16 points
    _, depth, theta0 = design("sobol", 16)
    for a in range(5):
        boxes = np.floor(depth * 2**a).astype(int) * 2 ** (4 - a) + np.floor(
            theta0 * 2 ** (4 - a)
        ).astype(int)
        assert sorted(boxes) == list(range(16)), a


def test_sobol_needs_a_power_of_two():
    with pytest.raises(InputError, match="power of two, not 12"):
        design("sobol", 12)


def _numeric_fields(model=Scene, prefix=""):
    """Every numeric leaf of the scene: (dotted path, its lower bound or None)."""
    for name, field in model.model_fields.items():
        if isinstance(field.annotation, type) and issubclass(field.annotation, BaseModel):
            yield from _numeric_fields(field.annotation, f"{prefix}{name}.")
        elif typing.get_origin(field.annotation) is not tuple and set(
            typing.get_args(field.annotation) or (field.annotation,)
        ) - {type(None)} <= {int, float}:
            bounds = (annotated_types.Ge, annotated_types.Gt)
            lower = [m for m in field.metadata if isinstance(m, bounds)]
            yield f"{prefix}{name}", lower[0] if lower else None


@pytest.mark.parametrize(("path", "lower"), list(_numeric_fields()), ids=lambda v: str(v))
def test_zero_negative_and_nan_are_refused_by_the_schema_naming_the_field(path, lower):
    # issue #37 item 14: the memory estimate read raw values before the schema checked
    # them (receiver.field_of_view_deg 0, transport.batches 0: ZeroDivisionError, exit 1);
    # every numeric field, in the default scene and swept, is refused naming itself (a
    # value below its bound, NaN: ``scene.PATH`` or ``sweep.parameters.PATH``) or
    # accepted, never a traceback
    data = yaml.safe_load(BASE)
    if path.startswith("transport."):  # read by the Monte Carlo renderer only
        data["scene"]["transport"] = {"method": "monte_carlo", "photons": 2000}
    for value in (0, -1, -1e300, math.nan):
        within = lower is None or (
            value >= lower.ge if isinstance(lower, annotated_types.Ge) else value > lower.gt
        )
        below = math.isnan(value) or not within
        scene = copy.deepcopy(data)
        assign(scene["scene"], path, value)
        swept = copy.deepcopy(data)
        swept["sweep"] = {"parameters": {path: {"values": [value]}}}
        for where, sweep_data in (("scene", scene), ("swept", swept)):
            try:
                parse_sweep(yaml.safe_dump(sweep_data))
            except InputError as error:
                assert not below or path in str(error), (where, value, str(error))
            else:
                assert not below, (where, value, "accepted")
