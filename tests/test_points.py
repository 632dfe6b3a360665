"""The points' scenes built on first use: a resume's cost follows what is missing (#26 item 8)."""

import numpy as np
import pytest

import workers.dataset.variables
from benchmarks.resume import build, sweep_text
from service.cli import main
from service.errors import BadSweepError
from service.store.location import Store
from service.sweep import parse_sweep

POINTS = 30


@pytest.fixture
def setups(monkeypatch):
    """The scenes set up (`workers.setup.builder.scene_setup`, by `count_dtype`) here."""
    seen = []
    setup = workers.dataset.variables.scene_setup

    def counted(scene):
        seen.append(scene)
        return setup(scene)

    monkeypatch.setattr(workers.dataset.variables, "scene_setup", counted)
    return seen


@pytest.fixture
def complete(tmp_path):
    """A complete store of `POINTS` random target depths, 2 realisations, 4 samples a shard,
    built without rendering (`benchmarks.resume.build`): its sweep file and URL."""
    return build(str(tmp_path), samples=2 * POINTS, points=POINTS, shard=4)


def test_a_fresh_plan_builds_and_checks_every_scene(setups):
    plan = parse_sweep(open_sweep(points=4), max_memory=None)
    assert plan.stored_image is None and len(plan.scenes.images) == 4 and len(setups) == 5
    bad = open_sweep(points=4).replace("min: 3.0, max: 5.0", "min: -5.0, max: -3.0")
    with pytest.raises(BadSweepError, match=r"parameter point 0 \(target\.depth="):
        parse_sweep(bad, max_memory=None)


def test_a_resumed_plan_builds_only_the_scenes_it_addresses(setups):
    plan = parse_sweep(
        open_sweep(points=POINTS), max_memory=None, resumed=lambda *_: np.dtype(np.uint16)
    )
    assert len(setups) == 1  # the default scene, checked by `read_header`
    assert plan.image_dtype() == np.uint16 and plan.samples == 2 * POINTS
    sample = plan.sample(2 * 17 + 1)
    assert sample.scene.target.depth == plan.points[17]["target.depth"]
    assert len(setups) == 2 and plan.scenes.images.keys() == {sample.scene}


def test_a_no_op_resume_sets_up_no_point(complete, setups):
    """Before: every point's scene was validated and set up by the admission (30 here)."""
    sweep, url = complete
    assert main(["-q", "run", sweep, "--output", url, "--resume", "--workers", "1"]) == 0
    # whatever the points: the default scene, the first point's (the store's kind) and
    # its variables at the two checks of the output (`check_output`)
    assert len(setups) <= 4


def test_a_resume_sets_up_the_missing_points_alone(complete, setups):
    sweep, url = complete
    points = parse_sweep(open(sweep).read(), max_memory=None).points
    setups.clear()
    Store.at(url).mark_incomplete([10, 11, 41])  # points 5 and 20
    assert main(["-q", "run", sweep, "--output", url, "--resume", "--workers", "1"]) == 0
    assert Store.at(url).completed().all()
    depths = {scene.target.depth for scene in setups}
    assert {points[5]["target.depth"], points[20]["target.depth"]} <= depths
    assert len(setups) <= 4 + 2


def test_a_resume_keeps_the_memory_limit_of_every_point(complete, capsys):
    sweep, url = complete
    args = ["run", sweep, "--output", url, "--resume", "--max-memory", "0.001"]
    assert main(args) == 2
    assert "over the limit" in capsys.readouterr().err


def test_a_resume_of_another_sweep_checks_every_point(complete, setups, tmp_path, capsys):
    sweep, url = complete
    other = tmp_path / "other.yaml"
    other.write_text(open(sweep).read().replace("seed: 1", "seed: 2"))
    assert main(["-q", "run", str(other), "--output", url, "--resume"]) == 2
    assert "holds a different sweep" in capsys.readouterr().err
    assert len(setups) > POINTS


def open_sweep(*, points: int) -> str:
    """The benchmark's sweep text: `points` random target depths, 2 realisations each."""
    return sweep_text(samples=2 * points, points=points)


def test_a_resume_reads_the_completion_flags_once(complete, monkeypatch):
    """Before: three times (the run's missing samples, the check after it, the statistics)."""
    sweep, url = complete
    Store.at(url).mark_incomplete([41])
    reads = []
    completed = Store.completed

    def counted(self, samples=None):
        reads.append(None if samples is None else list(samples))
        return completed(self, samples) if samples is not None else completed(self)

    monkeypatch.setattr(Store, "completed", counted)
    assert main(["-q", "run", sweep, "--output", url, "--resume", "--workers", "1"]) == 0
    assert reads == [None, [40, 41, 42, 43]]  # then only the shard the run wrote
