"""Below `workers/render.py` nothing reads the `Scene`: the compiled setup carries it (#38).

`workers.setup.builder.scene_setup` (with `workers.setup.seasetup`, which builds the sea
from its settings) reads a scene once and compiles it into a
`workers.setup.compiled.Setup`; the renderers read that. Each module of `workers/` below
the seam is parsed, and one that reads a scene fails: an import of the settings' scene
module outside ``if TYPE_CHECKING:``, any attribute named ``scene`` (``setup.scene.x``),
or a function taking a ``scene`` (by that name, or annotated ``Scene``), but for the named
functions of the dataset's contract (`CONTRACT`), which the service calls with a scene.
"""

import ast

import pytest
from conftest import ROOT

ABOVE = {"workers/render.py", "workers/fidelity.py"}
"""The two modules above the wings: the seam to the service, the renderers compared."""

READERS = ("workers/settings/", "workers/setup/builder.py", "workers/setup/seasetup.py")
"""What may read a scene: the settings themselves and the setup's builder."""

CONTRACT = {
    "workers/dataset/variables.py": {"white_plane_count", "count_dtype", "variables"},
    "workers/dataset/labels.py": {
        "sample_labels",
        "_label_variables",
        "rendered_arrays",
        "labelled_dataset",
        "image_axes",
        "surface_axis",
    },
}
"""The dataset's contract, which the service calls with a scene (the layout of a store, a
function of the settings, not yet of the compiled setup): these functions alone take one
(and their modules import `Scene` for it)."""

BELOW = sorted(
    path.relative_to(ROOT).as_posix()
    for path in (ROOT / "workers").rglob("*.py")
    if path.relative_to(ROOT).as_posix() not in ABOVE
    and not path.relative_to(ROOT).as_posix().startswith(READERS)
)


def _type_checking(node) -> bool:
    """Whether `node` is an ``if TYPE_CHECKING:`` block."""
    test = node.test
    name = test.attr if isinstance(test, ast.Attribute) else getattr(test, "id", None)
    return isinstance(node, ast.If) and name == "TYPE_CHECKING"


def _annotated_scene(annotation) -> bool:
    """Whether an annotation names ``Scene`` (bare, dotted or in a string)."""
    if annotation is None:
        return False
    text = ast.unparse(annotation)
    return "Scene" in text.replace("'", " ").replace('"', " ").replace(".", " ").split()


def scene_reads(source: str) -> list[str]:
    """Where `source` reads a scene: ``line: what``, one per read."""
    tree = ast.parse(source)
    hidden = {
        id(inner)
        for node in ast.walk(tree)
        if isinstance(node, ast.If) and _type_checking(node)
        for inner in ast.walk(node)
    }
    reads = []
    for node in ast.walk(tree):
        if id(node) in hidden:
            continue
        if isinstance(node, ast.ImportFrom) and node.module:
            names = {alias.name for alias in node.names}
            if node.module == "workers.settings.scene" or (
                node.module == "workers.settings" and "scene" in names
            ):
                reads.append(f"{node.lineno}: imports {node.module} ({', '.join(sorted(names))})")
        elif isinstance(node, ast.Import):
            for alias in node.names:
                if alias.name == "workers.settings.scene":
                    reads.append(f"{node.lineno}: imports {alias.name}")
        elif isinstance(node, ast.Attribute) and node.attr == "scene":
            reads.append(f"{node.lineno}: reads {ast.unparse(node)}")
        elif isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef):
            arguments = node.args
            for argument in (
                *arguments.posonlyargs,
                *arguments.args,
                *arguments.kwonlyargs,
                *(a for a in (arguments.vararg, arguments.kwarg) if a is not None),
            ):
                if argument.arg == "scene" or _annotated_scene(argument.annotation):
                    reads.append(f"{node.lineno}: {node.name} takes a scene ({argument.arg})")
    return reads


def _contract(read: str, path: str) -> bool:
    """Whether `read` is the dataset's contract taking a scene (or importing `Scene`)."""
    allowed = CONTRACT.get(path, set())
    what = read.split(": ", 1)[1]
    return bool(allowed) and (
        what == "imports workers.settings.scene (Scene)"
        or what.split(" takes a scene")[0] in allowed
    )


@pytest.mark.parametrize("path", BELOW)
def test_below_the_seam_nothing_reads_the_scene(path):
    reads = scene_reads((ROOT / path).read_text())
    assert [read for read in reads if not _contract(read, path)] == []


def test_the_seams_exceptions_are_few_and_the_renderers_are_held():
    # the wings that render are all held; the exceptions are the settings and the builder
    held = {path.split("/")[1] for path in BELOW if path.count("/") == 2}
    assert {"backends", "optics", "receiver", "sea", "targets", "setup"} <= held
    assert {"fast", "montecarlo", "detectors", "dataset"} <= held
    assert "workers/setup/compiled.py" in BELOW and "workers/setup/sensor.py" in BELOW
    assert "workers/render.py" not in BELOW and "workers/setup/builder.py" not in BELOW
    assert set(CONTRACT) <= set(BELOW)


def test_the_dataset_may_take_a_scene_in_its_contract_alone():
    path = "workers/dataset/labels.py"
    reads = scene_reads("def image_axes(scene):\n    return 1\n")
    assert reads and _contract(reads[0], path)
    reads = scene_reads("def target_mask(share, scene):\n    return 1\n")
    assert reads and not _contract(reads[0], path)
    reads = scene_reads("def mask(setup):\n    return setup.scene.target\n")
    assert reads and not _contract(reads[0], path)


@pytest.mark.parametrize(
    ("source", "read"),
    [
        ("from workers.settings.scene import Scene\n", "imports workers.settings.scene"),
        ("import workers.settings.scene\n", "imports workers.settings.scene"),
        ("from workers.settings import scene\n", "imports workers.settings"),
        ("def f(setup):\n    return setup.scene.target\n", "reads setup.scene"),
        ("def f(self):\n    return self.setup.scene\n", "reads self.setup.scene"),
        ("def f(scene):\n    return 1\n", "f takes a scene (scene)"),
        ("def f(*, s: 'Scene'):\n    return 1\n", "f takes a scene (s)"),
        ("def f(s: settings.Scene):\n    return 1\n", "f takes a scene (s)"),
    ],
)
def test_each_way_of_reading_a_scene_is_caught(source, read):
    reads = scene_reads(source)
    assert len(reads) == 1 and read in reads[0], reads


def test_a_scene_named_only_for_type_checking_or_in_words_is_not_a_read():
    source = (
        "from typing import TYPE_CHECKING\n"
        "if TYPE_CHECKING:\n"
        "    from workers.settings.scene import Scene\n"
        'def f(setup, scenes: list, sceneless: "SceneError"):\n'
        '    """Of the scene\'s setup (`Scene.laser_rays`)."""\n'
        "    return setup.water.scenery\n"
    )
    assert scene_reads(source) == []
