"""The shipped sweep files: each runs end to end, and each says what it models."""

import ast
import re
import shutil

import numpy as np
import pytest
import xarray as xr
import yaml
from conftest import ROOT

from service.cli import main
from service.sweep import load_sweep

CONFIGS = sorted((ROOT / "configs").rglob("*.yaml"))
"""Every sweep file shipped, found anew each run: a new config is tested without edits."""

SMALL_GRID = 32
"""Surface grid points per side in the reduced runs (the patch keeps its size)."""

SMALL_PIXELS = 16
"""Receiver pixels per side in the reduced runs."""

MAX_POINTS = 24
"""Parameter points kept of a random design (mldc-detection.yaml draws 2000)."""


def reduced(path, folder):
    """A copy of the sweep file at `path`, made small, written into `folder`.

    One realisation per point; a coarser surface grid over the same patch (grid_size ×
    spacing kept, or the default spacing left to cover the footprint, so the footprint
    check and conditioning points see the same finest patch);
    fewer pixels. A random design keeps its first `MAX_POINTS` draws (its parameters'
    ranges are unchanged, but fewer of its points run). Nothing else is changed: the
    physics, sequences, sweeps and gates are as shipped. A conditioning file is copied
    beside the copy (measurement files must lie in the sweep file's folder).
    """
    sweep = yaml.safe_load(path.read_text())
    sweep["realisations"] = 1
    surface = sweep.setdefault("scene", {}).setdefault("surface", {})
    size, surface["grid_size"] = surface.get("grid_size", 256), SMALL_GRID
    if surface.get("spacing") is not None:
        surface["spacing"] = size * surface["spacing"] / SMALL_GRID
    sweep["scene"].setdefault("receiver", {})["pixels"] = SMALL_PIXELS
    conditioning = surface.get("conditioning", {})
    if "file" in conditioning:
        shutil.copy(path.parent / conditioning["file"], folder / conditioning["file"])
    design = sweep.get("sweep", {})
    if design.get("method") == "random":
        design["count"] = min(design["count"], MAX_POINTS)
    copy = folder / path.name
    copy.write_text(yaml.safe_dump(sweep))
    return copy


@pytest.fixture(scope="module")
def scheduler(session_cluster):
    """The session's cluster, that every config's run joins."""
    return session_cluster.scheduler.address


@pytest.mark.parametrize("path", CONFIGS, ids=[str(p.relative_to(ROOT)) for p in CONFIGS])
def test_every_shipped_config_runs_end_to_end(path, tmp_path, scheduler, monkeypatch):
    # Issue #9, item 9: a shipped example must never crash, nor write bad samples. The
    # command line's `run`, in this process, on one cluster for all (a cluster each cost
    # more than most of these runs).
    sweep = reduced(path, tmp_path)
    store = tmp_path / "out.zarr"
    monkeypatch.chdir(tmp_path)
    assert main(["run", str(sweep), "--output", str(store), "--scheduler", scheduler]) == 0
    with xr.open_zarr(store) as ds:
        assert ds.sizes["sample"] > 0
        assert ds.completed.values.all()
        image = ds["image"].values
        assert np.isfinite(image).all() and (image >= 0).all()


OUTSIDE_PAPER = [path for path in CONFIGS if "paper" not in path.relative_to(ROOT).parts[1:-1]]


@pytest.mark.parametrize(
    "path", OUTSIDE_PAPER, ids=[str(p.relative_to(ROOT)) for p in OUTSIDE_PAPER]
)
def test_only_the_papers_examples_use_the_papers_shading(path):
    # Issue #9, item 5: `shading: paper` does not conserve energy (a white sphere returns
    # twice a white disk of its radius); it is there to reproduce the paper's figures.
    # Every scene of the sweep counts, defaults and swept values included.
    plan = load_sweep(path)
    assert {scene.target.shading for scene in plan.scenes} == {"lambert"}


MODULES = sorted(
    path for package in ("workers", "service") for path in (ROOT / package).rglob("[!_]*.py")
)
PACKAGES = sorted(
    path for package in ("workers", "service") for path in (ROOT / package).rglob("__init__.py")
)


def module_name(path):
    """The dotted name of a module or package of the project (``service.store.location``)."""
    parts = path.relative_to(ROOT).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def code_lines(path):
    """Lines of code: docstrings (module, class, function), comments and blanks aside."""
    source = path.read_text()
    docstrings = set()
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Module | ast.ClassDef | ast.FunctionDef | ast.AsyncFunctionDef):
            first = node.body[0] if node.body else None
            if isinstance(first, ast.Expr) and isinstance(first.value, ast.Constant):
                if isinstance(first.value.value, str):
                    docstrings.update(range(first.lineno, first.end_lineno + 1))
    return sum(
        1
        for number, line in enumerate(source.splitlines(), 1)
        if line.strip() and not line.strip().startswith("#") and number not in docstrings
    )


def architecture_section(folder):
    """The text of ARCHITECTURE.md under the heading that names `folder` (``workers/fast/``).

    From that heading to the next heading of any level.
    """
    text = (ROOT / "ARCHITECTURE.md").read_text()
    heading = re.search(rf"^#+ {re.escape(folder)}(?: |$)", text, flags=re.M)
    assert heading, f"ARCHITECTURE.md has no heading for {folder}"
    after = text[heading.end() :]
    following = re.search(r"^#", after, flags=re.M)
    return after[: following.start()] if following else after


@pytest.mark.parametrize("path", MODULES, ids=[module_name(p) for p in MODULES])
def test_every_module_is_small_and_in_the_architecture(path):
    # issue #38 item 6: each module's row under its own folder's heading
    assert code_lines(path) <= 350
    folder = path.parent.relative_to(ROOT).as_posix() + "/"
    assert f"| `{path.name}` |" in architecture_section(folder)


def _project_imports(path, modules):
    """The project modules `path` imports, at its top or inside functions.

    ``from PACKAGE import NAME`` imports the module ``PACKAGE.NAME`` where there is one
    (`modules`), else the package.
    """
    names = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.module:
            if node.module.split(".")[0] in ("workers", "service"):
                for alias in node.names:
                    inner = f"{node.module}.{alias.name}"
                    names.add(inner if inner in modules else node.module)
        elif isinstance(node, ast.Import):
            names.update(
                a.name for a in node.names if a.name.split(".")[0] in ("workers", "service")
            )
    return names


def test_no_import_circle():
    # issue #13: modules import in one direction (a lazy import inside a function counts)
    modules = {module_name(p): p for p in MODULES + PACKAGES}
    graph = {name: _project_imports(path, modules) for name, path in modules.items()}
    done, path = set(), []

    def visit(module):
        if module in path:
            raise AssertionError(" -> ".join([*path[path.index(module) :], module]))
        if module in done or module not in graph:
            return
        path.append(module)
        for imported in sorted(graph[module]):
            visit(imported)
        path.pop()
        done.add(module)

    for module in sorted(graph):
        visit(module)


WINGS = (
    "backends",
    "optics",
    "receiver",
    "sea",
    "targets",
    "settings",
    "setup",
    "dataset",
    "fast",
    "montecarlo",
    "calibration",
    "detectors",
)
"""The sub-packages of `workers`, lowest first: a wing imports only the wings before it."""


def test_the_wings_import_down_only():
    # issue #38 item 4: no circles, no import back up; render.py and fidelity.py sit above
    modules = {module_name(p): p for p in MODULES + PACKAGES}
    wings = {path.parent.name for path in (ROOT / "workers").glob("*/__init__.py")}
    assert wings == set(WINGS)
    for name, path in modules.items():
        parts = name.split(".")
        if parts[0] != "workers" or len(parts) < 3:
            continue
        rank = WINGS.index(parts[1])
        for imported in _project_imports(path, modules):
            target = imported.split(".")
            if target[0] == "service":
                raise AssertionError(f"{name} imports the service ({imported})")
            assert len(target) > 2 and target[1] in WINGS, f"{name} imports {imported} above it"
            assert WINGS.index(target[1]) <= rank, f"{name} imports {imported}, a higher wing"
