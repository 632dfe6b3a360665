"""Tests of workers.conditioning: surfaces drawn given measured elevations (issue #5)."""

import json
import textwrap
from pathlib import Path

import numpy as np
import pytest
from numpy.testing import assert_allclose
from pydantic import ValidationError

from service.inputs import SweepError
from service.plots import preview_figure
from service.sweep import load_sweep, parse_sweep
from workers.conditioning import kriging, space_time_covariance
from workers.render import render
from workers.scene import Scene
from workers.section import SceneError
from workers.spectra import Elfouhaily, dispersion
from workers.surface import surface_amplitudes, synthesize

# 64 × 1 m: a 3 m/s sea whose correlation falls below 4 % beyond 8 m and 0.5 % beyond 16 m,
# so "far from the data" exists on the patch.
N, SPACING = 64, 1.0
SEA = Elfouhaily(wind_speed=3.0)
CONFIGS = Path(__file__).resolve().parent.parent / "configs"


def mode_sum_covariance(spectrum, n, spacing, dx, dy, lag):
    """Oracle: Σ_k a² cos(k·Δx − ω Δt) summed mode by mode (float64 a from float32)."""
    a = surface_amplitudes(spectrum, grid_size=n, spacing=spacing).astype(np.float32)
    k = 2 * np.pi * np.fft.fftfreq(n, d=spacing)
    kx, ky = k[None, :], k[:, None]
    omega = dispersion(np.hypot(kx, ky))
    phase = (
        kx[..., None] * np.asarray(dx) + ky[..., None] * np.asarray(dy) - omega[..., None] * lag
    )
    return np.einsum("ij,ijp->p", a.astype(np.float64) ** 2, np.cos(phase))


def stencil(x, y, spacing):
    """Bilinear nodes (x, y) and weights of a point, as Surface.sample interpolates."""
    j, i = np.floor(x / spacing), np.floor(y / spacing)
    fx, fy = x / spacing - j, y / spacing - i
    nodes = [(j, i), (j + 1, i), (j, i + 1), (j + 1, i + 1)]
    weights = [(1 - fx) * (1 - fy), fx * (1 - fy), (1 - fx) * fy, fx * fy]
    return [(a * spacing, b * spacing) for a, b in nodes], weights


def point_covariance(p, q):
    """Oracle Cov(η(p), η(q)) of bilinear point values p, q = (x, y, t)."""
    (nodes_p, w_p), (nodes_q, w_q) = stencil(*p[:2], SPACING), stencil(*q[:2], SPACING)
    dx = [a[0] - b[0] for a in nodes_p for b in nodes_q]
    dy = [a[1] - b[1] for a in nodes_p for b in nodes_q]
    c = mode_sum_covariance(SEA, N, SPACING, dx, dy, p[2] - q[2])
    return float(np.outer(w_p, w_q).ravel() @ c)


def kriging_oracle(data, noise, location):
    """Simple-kriging mean and variance of η at `location` (x, y, t) given `data`."""
    K = np.array([[point_covariance(p, q) for q in data] for p in data])
    K += noise**2 * np.eye(len(data))
    c = np.array([point_covariance(location, p) for p in data])
    d = np.array([p[3] for p in data])
    weights = np.linalg.solve(K, c)
    return weights @ d, point_covariance(location, location) - weights @ c


def points_of(data):
    """(x, y, elevation, time) oracle tuples as the scene's [x, y, elevation, time]."""
    return tuple((x, y, e, t) for x, y, t, e in data)


class BasisGenerator:
    """Stands in for a Generator: its one draw is the unit vector e_index."""

    def __init__(self, index):
        self.index = index

    def standard_normal(self, *, out, dtype):
        out[...] = 0
        out.reshape(-1)[self.index] = 1


def test_covariance_is_the_mode_sum():
    n, spacing = 16, 0.3
    dx, dy = np.meshgrid(np.arange(n) * spacing, np.arange(n) * spacing)
    variance = space_time_covariance(SEA, grid_size=n, spacing=spacing)[0, 0]
    for lag in (0.0, 0.7):
        grid = space_time_covariance(SEA, grid_size=n, spacing=spacing, lag=lag)
        oracle = mode_sum_covariance(SEA, n, spacing, dx.ravel(), dy.ravel(), lag)
        assert_allclose(grid.ravel(), oracle, rtol=0, atol=1e-12 * variance)


def test_covariance_is_that_of_the_synthesised_field_exactly():
    # The field is linear in its 2N² normals, η = A ξ, so its covariance is A Aᵀ:
    # push each unit vector through the synthesis (standing Nyquist modes included).
    n, spacing, times = 8, 0.5, (0.0, 0.9)
    columns = [
        synthesize(SEA, grid_size=n, spacing=spacing, rng=BasisGenerator(i), times=times)
        .elevation.reshape(len(times), -1)
        .astype(np.float64)
        for i in range(2 * n * n)
    ]
    A = np.stack(columns, axis=-1)  # (time, node, normal)
    variance = space_time_covariance(SEA, grid_size=n, spacing=spacing)[0, 0]
    for lag, (later, earlier) in ((0.0, (0, 0)), (0.9, (1, 0))):
        covariance = A[later] @ A[earlier].T  # Cov(η(node_a, t_later), η(node_b, t_earlier))
        grid = space_time_covariance(SEA, grid_size=n, spacing=spacing, lag=lag)
        rows, cols = np.divmod(np.arange(n * n), n)
        expected = grid[(rows[:, None] - rows[None]) % n, (cols[:, None] - cols[None]) % n]
        # float32 synthesis: rounding of 6e-8 relative on each of the 2N² terms
        assert_allclose(covariance, expected, rtol=0, atol=1e-6 * variance)


def test_no_data_equals_unconditional_bytes():
    base = {"surface": {"grid_size": 32, "spacing": 0.128}, "receiver": {"pixels": 16}}
    empty = {**base, "surface": {**base["surface"], "conditioning": {"points": [], "noise": 0.1}}}
    plain = render(Scene.model_validate(base), seed=4)
    for scene in (empty, {**base, "surface": {**base["surface"], "conditioning": {}}}):
        other = render(Scene.model_validate(scene), seed=4)
        assert other.image.values.tobytes() == plain.image.values.tobytes()
        assert other.expected.values.tobytes() == plain.expected.values.tobytes()


@pytest.mark.parametrize("off_node", [False, True], ids=["on-nodes", "between-nodes"])
def test_data_are_honoured_to_rounding_without_noise(off_node):
    shift = 0.37 if off_node else 0.0
    data = ((3.0 + shift, 5.0, 0.1, 0.0), (20.0, 41.0 + shift, -0.08, 0.0), (63.5, 0.2, 0.05, 0))
    system = kriging(SEA, grid_size=N, spacing=SPACING, points=data, noise=0.0)
    x, y, elevation, _ = np.array(data).T
    for seed in range(3):
        surface = synthesize(
            SEA, grid_size=N, spacing=SPACING, rng=np.random.default_rng(seed), conditioning=system
        )
        # float32 fields of a few cm: rounding ~1e-8 m
        assert_allclose(surface.elevation_at(x, y), elevation, rtol=0, atol=1e-6)


def test_data_condition_every_frame_and_the_correction_travels():
    # One datum at t = 0.5 s, no noise: the correction is w C(x − x_d, t − t_d), with
    # w = (d − η_u(x_d, t_d)) / C(0, 0): a shifted copy of the space–time covariance.
    x_d, y_d, t_d, d = 10.0, 30.0, 0.5, 0.15
    times = (0.0, 0.5, 2.0)
    system = kriging(SEA, grid_size=N, spacing=SPACING, points=((x_d, y_d, d, t_d),), noise=0.0)
    free = synthesize(SEA, grid_size=N, spacing=SPACING, rng=np.random.default_rng(2), times=times)
    tied = synthesize(
        SEA,
        grid_size=N,
        spacing=SPACING,
        rng=np.random.default_rng(2),
        times=times,
        conditioning=system,
    )
    assert tied.elevation_at(x_d, y_d, frame=1) == pytest.approx(d, abs=1e-6)
    c0 = space_time_covariance(SEA, grid_size=N, spacing=SPACING)[0, 0]
    weight = (d - float(free.elevation_at(x_d, y_d, frame=1))) / c0
    nodes = np.arange(N) * SPACING
    dx, dy = np.meshgrid(nodes - x_d, nodes - y_d)
    for frame, t in enumerate(times):
        kernel = mode_sum_covariance(SEA, N, SPACING, dx.ravel(), dy.ravel(), t - t_d)
        correction = (tied.elevation[frame] - free.elevation[frame]).ravel()
        assert_allclose(correction, weight * kernel, rtol=0, atol=1e-5 * abs(weight) * c0)
    # slopes are corrected too: the slope of the correction is that of the kernel
    assert not np.array_equal(tied.slope_x[0], free.slope_x[0])


def test_draws_have_the_kriging_mean_and_variance():
    # Data at two times (0 and 1 s), one between nodes; frames at 0 and 2 s. Over M
    # draws the sample mean is within 5 standard errors sqrt(v/M) of the kriging mean,
    # and the sample variance within 5 sqrt(2/(M-1)) (relative) of the kriging variance
    # (Gaussian sample variance), at test points on the data, between, and far away.
    noise, draws, times = 0.01, 2000, (0.0, 2.0)
    data = [(8.0, 8.0, 0.0, 0.12), (12.3, 9.0, 0.0, -0.05), (9.0, 14.0, 1.0, 0.03)]
    system = kriging(SEA, grid_size=N, spacing=SPACING, points=points_of(data), noise=noise)
    locations = [(8.0, 8.0, 0), (10.0, 11.0, 0), (10.0, 11.0, 1), (40.0, 40.0, 0)]
    rng = np.random.default_rng(11)
    values = np.empty((draws, len(locations)))
    for m in range(draws):
        surface = synthesize(
            SEA, grid_size=N, spacing=SPACING, rng=rng, times=times, conditioning=system
        )
        for p, (x, y, frame) in enumerate(locations):
            values[m, p] = surface.elevation_at(x, y, frame=frame)
    prior = point_covariance((0, 0, 0), (0, 0, 0))
    for p, (x, y, frame) in enumerate(locations):
        mean, variance = kriging_oracle(data, noise, (x, y, times[frame]))
        assert abs(values[:, p].mean() - mean) < 5 * np.sqrt(variance / draws)
        assert abs(values[:, p].var(ddof=1) / variance - 1) < 5 * np.sqrt(2 / (draws - 1))
    # at the first datum the spread is below the noise; far away it is the prior's
    assert kriging_oracle(data, noise, (8.0, 8.0, 0.0))[1] < noise**2
    far_mean, far_variance = kriging_oracle(data, noise, (40.0, 40.0, 0.0))
    assert far_variance > 0.999 * prior and abs(far_mean) < 0.01 * abs(data[0][3])
    far = values[:, 3].var(ddof=1)
    assert abs(far / prior - 1) < 5 * np.sqrt(2 / (draws - 1))


@pytest.mark.parametrize(
    ("conditioning", "surface", "message"),
    [
        ({"points": [[70.0, 3.0, 0.1]]}, {}, "off the surface grid"),
        ({"points": [[-1.0, 3.0, 0.1]]}, {}, "x=63 m, y=3 m"),
        ({"points": [[1.0, 3.0, 0.1], [1.0, 3.0, 0.2]]}, {}, "points 0 and 1"),
        ({"points": [[1.0, 3.0, 0.1]]}, {"spectrum": "flat"}, "flat sea"),
        ({"points": [[1.0, 3.0, 0.1]]}, {"max_elevation": 0.1}, "max_elevation"),
        ({"points": [[1.0, 3.0]]}, {}, "at least 3"),
        ({"points": [[1.0, 3.0, 0.1]], "noise": -1.0}, {}, "noise"),
    ],
    ids=[
        "off-grid",
        "negative",
        "duplicate",
        "flat",
        "max-elevation",
        "short",
        "noise",
    ],
)
def test_bad_conditioning_is_refused_with_the_field(conditioning, surface, message):
    surface = {"grid_size": N, "spacing": SPACING, "wind_speed": 3.0, **surface}
    with pytest.raises(ValidationError) as error:
        Scene.model_validate({"surface": {**surface, "conditioning": conditioning}})
    assert message in str(error.value) and "conditioning" in str(error.value)


def test_validation_checks_points_without_building_the_system():
    surface = {"grid_size": N, "spacing": SPACING, "wind_speed": 3.0}
    near = [[1.0, 3.0, 0.1], [1.000001, 3.0, 0.1]]  # distinct, but a singular system
    kriging.cache_clear()
    scene = Scene.model_validate({"surface": {**surface, "conditioning": {"points": near}}})
    assert kriging.cache_info().misses == 0
    with pytest.raises(SceneError, match=r"surface\.conditioning\.points: .*ill-conditioned"):
        scene.surface.kriging()  # built to render, where the error is the input's


def test_singular_systems_name_the_redundant_points():
    with pytest.raises(ValueError, match=r"points 1 \(2, 3 m, t=0 s\), 2 \(2, 3 m, t=0 s\)"):
        kriging(
            SEA,
            grid_size=N,
            spacing=SPACING,
            points=((40.0, 40.0, 0.0), (2.0, 3.0, 0.1), (2.0 + 1e-7, 3.0, 0.1)),
            noise=0.0,
        )


SWEEP = """\
name: c
seed: 1
output: c.zarr
scene:
  surface:
    grid_size: 64
    spacing: 1.0
    wind_speed: 3.0
    conditioning: {conditioning}
  receiver: {{pixels: 16}}
  save_surface: true
"""


def write_sweep(folder, conditioning, csv=None):
    if csv is not None:
        (folder / "data").mkdir()
        (folder / "data" / "points.csv").write_text(textwrap.dedent(csv))
    path = folder / "sweep.yaml"
    path.write_text(SWEEP.format(conditioning=conditioning))
    return path


def test_csv_points_are_read_relative_to_the_sweep_and_honoured(tmp_path, monkeypatch):
    csv = """\
        # buoy readings
        x,y,elevation,time
        5.0,6.0,0.1,0.0

        30.5,20.0,-0.05,0.0
        """
    path = write_sweep(tmp_path, "{file: data/points.csv, noise: 0.0}", csv)
    monkeypatch.chdir("/")
    plan = load_sweep(path)
    points = plan.scenes[0].surface.conditioning.points
    assert points == ((5.0, 6.0, 0.1, 0.0), (30.5, 20.0, -0.05, 0.0))
    listed = json.dumps(points)
    inline = parse_sweep(path.read_text().replace("{file: data/points.csv", f"{{points: {listed}"))
    assert inline.digest == plan.digest  # the digest covers the values, not the file name
    ds = render(plan.scenes[0], seed=plan.sweep.seed)
    eta = ds.surface_elevation.values[0]
    assert eta[6, 5] == pytest.approx(0.1, abs=1e-6)
    assert 0.5 * (eta[20, 30] + eta[20, 31]) == pytest.approx(-0.05, abs=1e-6)


@pytest.mark.parametrize(
    ("conditioning", "csv", "message"),
    [
        ("{file: data/points.csv}", "x,y,z\n1,2,3\n", "header"),
        ("{file: data/points.csv}", "x,y,elevation\n1,2\n", "line 2: expected 3"),
        ("{file: data/points.csv}", "x,y,elevation\n1,2,nan\n", "finite"),
        ("{file: data/points.csv}", "x,y,elevation\n", "no points"),
        ("{file: data/missing.csv}", "x,y,elevation\n1,2,3\n", "No such file"),
        ("{file: data/points.csv, points: [[1, 2, 3]]}", "x,y,elevation\n1,2,3\n", "not both"),
        ("{file: data/points.csv}", "x,y,elevation\n99,2,0.1\n", "off the surface grid"),
    ],
    ids=["header", "short-row", "nan", "empty", "missing", "both", "off-grid"],
)
def test_bad_csv_files_are_refused(tmp_path, conditioning, csv, message):
    path = write_sweep(tmp_path, conditioning, csv)
    with pytest.raises(SweepError, match=r"scene\.surface") as error:
        load_sweep(path)
    assert message in str(error.value)


def test_preview_marks_the_measured_points():
    plan = load_sweep(CONFIGS / "conditioned.yaml")
    points = plan.scenes[0].surface.conditioning.points
    scene = plan.scenes[0].model_copy(
        update={"receiver": plan.scenes[0].receiver.model_copy(update={"pixels": 16})}
    )
    figure = preview_figure(render(scene, seed=0), measurements=points)
    (sea,) = [ax for ax in figure.axes if ax.get_title().startswith("sea")]
    (marks,) = [line for line in sea.get_lines() if len(line.get_xdata()) == len(points)]
    assert_allclose(marks.get_xdata(), [p[0] for p in points])
    assert_allclose(marks.get_ydata(), [p[1] for p in points])
