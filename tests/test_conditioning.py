"""Tests of workers.sea.conditioning: surfaces drawn given measured elevations (issue #5)."""

import json
import textwrap
from pathlib import Path

import numpy as np
import pytest
from numpy.testing import assert_allclose
from pydantic import ValidationError

from service.errors import InputError
from service.plots import preview_figure
from service.sweep import load_sweep, parse_sweep
from workers.render import render
from workers.sea.cascades import Sea
from workers.sea.conditioning import kriging, space_time_covariance
from workers.sea.spectra import Elfouhaily, dispersion
from workers.sea.surface import draw
from workers.settings.scene import Scene
from workers.settings.section import SceneError
from workers.setup.seasetup import scene_sea, surface_kriging

# 64 × 1 m: a 3 m/s sea whose correlation falls below 4 % beyond 8 m and 0.5 % beyond 16 m,
# so "far from the data" exists on the patch.
N, SPACING = 64, 1.0
SEA = Elfouhaily(wind_speed=3.0)
ONE = Sea(SEA, N, (N * SPACING,))
# The same sea in three cascades of 64 points: 4, 16 and 64 m. The finer cascades are
# periodic, so data condition them at their images too: a place far from the data is
# also far from those images (x and y ≡ 1 m mod 4 and mod 16, 9.9 m from the nearest).
THREE = Sea(SEA, N, (4.0, 16.0, 64.0))
CONFIGS = Path(__file__).resolve().parent.parent / "configs"


def mode_sum_covariance(sea, dx, dy, lag):
    """Oracle: Σ_c Σ_k a_c² cos(k·Δx − ω Δt) summed mode by mode (float64 a from float32)."""
    return sum(cascade_covariance(sea, c, dx, dy, lag) for c in range(len(sea.patches)))


def cascade_covariance(sea, cascade, dx, dy, lag):
    """Oracle: Σ_k a_c² cos(k·Δx − ω Δt) of one cascade."""
    a = sea.amplitudes(cascade).astype(np.float32)
    k = sea.wavenumbers(cascade)
    kx, ky = k[None, :], k[:, None]
    omega = dispersion(np.hypot(kx, ky))
    phase = kx[..., None] * np.asarray(dx) + ky[..., None] * np.asarray(dy)
    phase -= omega[..., None] * lag
    return np.einsum("ij,ijp->p", a.astype(np.float64) ** 2, np.cos(phase))


def conditioned(system, rng, times=(0.0,)):
    """A conditioned draw: the unconditional modes, corrected, evolved to `times`."""
    return system.condition(draw(system.sea, rng), rng).surface(times)


def free(sea, rng, times=(0.0,)):
    return draw(sea, rng).surface(times)


def stencil(x, y, spacing):
    """Bilinear nodes (x, y) and weights of a point, as Surface.sample interpolates."""
    j, i = np.floor(x / spacing), np.floor(y / spacing)
    fx, fy = x / spacing - j, y / spacing - i
    nodes = [(j, i), (j + 1, i), (j, i + 1), (j + 1, i + 1)]
    weights = [(1 - fx) * (1 - fy), fx * (1 - fy), (1 - fx) * fy, fx * fy]
    return [(a * spacing, b * spacing) for a, b in nodes], weights


def point_covariance(p, q, sea=ONE):
    """Oracle Cov(η(p), η(q)) of point values p, q = (x, y, t): bilinear on every cascade."""
    total = 0.0
    for cascade in range(len(sea.patches)):
        spacing = sea.spacing(cascade)
        (nodes_p, w_p), (nodes_q, w_q) = stencil(*p[:2], spacing), stencil(*q[:2], spacing)
        dx = [a[0] - b[0] for a in nodes_p for b in nodes_q]
        dy = [a[1] - b[1] for a in nodes_p for b in nodes_q]
        c = cascade_covariance(sea, cascade, dx, dy, p[2] - q[2])
        total += float(np.outer(w_p, w_q).ravel() @ c)
    return total


def kriging_oracle(data, noise, location, sea=ONE):
    """Simple-kriging mean and variance of η at `location` (x, y, t) given `data`."""
    K = np.array([[point_covariance(p, q, sea) for q in data] for p in data])
    K += noise**2 * np.eye(len(data))
    c = np.array([point_covariance(location, p, sea) for p in data])
    d = np.array([p[3] for p in data])
    weights = np.linalg.solve(K, c)
    return weights @ d, point_covariance(location, location, sea) - weights @ c


def points_of(data):
    """(x, y, elevation, time) oracle tuples as the scene's [x, y, elevation, time]."""
    return tuple((x, y, e, t) for x, y, t, e in data)


class BasisGenerator:
    """Stands in for a Generator: its one draw of normals is the unit vector e_index."""

    def __init__(self, index):
        self.index = index

    def standard_normal(self, *, out, dtype):
        out[...] = 0
        out.reshape(-1)[self.index] = 1

    def integers(self, low, high, dtype):
        return 0


@pytest.mark.parametrize("cascade", [0, 1], ids=["finest", "coarser"])
def test_covariance_is_the_mode_sum(cascade):
    sea = Sea(SEA, 32, (9.6, 19.2))
    spacing = sea.spacing(cascade)
    dx, dy = np.meshgrid(np.arange(32) * spacing, np.arange(32) * spacing)
    variance = space_time_covariance(sea, cascade=cascade)[0, 0]
    for lag in (0.0, 0.7):
        grid = space_time_covariance(sea, cascade=cascade, lag=lag)
        oracle = cascade_covariance(sea, cascade, dx.ravel(), dy.ravel(), lag)
        assert_allclose(grid.ravel(), oracle, rtol=0, atol=1e-12 * variance)


def test_covariance_is_that_of_the_synthesised_field_exactly():
    # The field is linear in its 2N² normals, η = A ξ, so its covariance is A Aᵀ:
    # push each unit vector through the synthesis.
    n, spacing, times = 8, 0.5, (0.0, 0.9)
    sea = Sea(SEA, n, (n * spacing,))
    columns = [
        free(sea, [BasisGenerator(i)], times).elevation.reshape(len(times), -1).astype(np.float64)
        for i in range(2 * n * n)
    ]
    A = np.stack(columns, axis=-1)  # (time, node, normal)
    variance = space_time_covariance(sea)[0, 0]
    for lag, (later, earlier) in ((0.0, (0, 0)), (0.9, (1, 0))):
        covariance = A[later] @ A[earlier].T  # Cov(η(node_a, t_later), η(node_b, t_earlier))
        grid = space_time_covariance(sea, lag=lag)
        rows, cols = np.divmod(np.arange(n * n), n)
        expected = grid[(rows[:, None] - rows[None]) % n, (cols[:, None] - cols[None]) % n]
        # float32 synthesis: rounding of 6e-8 relative on each of the 2N² terms
        assert_allclose(covariance, expected, rtol=0, atol=1e-6 * variance)


class ZeroGenerator(BasisGenerator):
    """Stands in for a Generator whose normals are all zero."""

    def __init__(self):
        super().__init__(slice(0, 0))


def test_a_coarser_cascade_drawn_on_its_bands_square_has_its_whole_covariance():
    # A coarser cascade's band ends at a quarter of its Nyquist wavenumber: its modes
    # vanish outside the square |i|, |j| <= m, and the 2M² normals of that square
    # (M = 2m + 1) alone must give its field the whole space-time covariance.
    n, times = 32, (0.0, 0.9)
    sea = Sea(SEA, n, (9.6, 19.2))
    signed = np.abs(np.fft.fftfreq(n, d=1.0 / n))
    rows, cols = np.nonzero(sea.amplitudes(1))
    side = 2 * int(max(signed[rows].max(), signed[cols].max())) + 1
    assert side <= n // 4 + 1
    columns = [
        draw(sea, [ZeroGenerator(), BasisGenerator(i)])
        .surface(times)
        .cascades[1]
        .elevation.reshape(len(times), -1)
        .astype(np.float64)
        for i in range(2 * side * side)
    ]
    A = np.stack(columns, axis=-1)
    variance = space_time_covariance(sea, cascade=1)[0, 0]
    for lag, (later, earlier) in ((0.0, (0, 0)), (0.9, (1, 0))):
        grid = space_time_covariance(sea, cascade=1, lag=lag)
        r, c = np.divmod(np.arange(n * n), n)
        expected = grid[(r[:, None] - r[None]) % n, (c[:, None] - c[None]) % n]
        assert_allclose(A[later] @ A[earlier].T, expected, rtol=0, atol=1e-6 * variance)


def test_no_data_equals_unconditional_bytes():
    base = {"surface": {"grid_size": 32, "spacing": 0.128}, "receiver": {"pixels": 16}}
    empty = {**base, "surface": {**base["surface"], "conditioning": {"points": [], "noise": 0.1}}}
    plain = render(Scene.model_validate(base), seed=4)
    for scene in (empty, {**base, "surface": {**base["surface"], "conditioning": {}}}):
        other = render(Scene.model_validate(scene), seed=4)
        assert other.image.values.tobytes() == plain.image.values.tobytes()
        assert other.expected.values.tobytes() == plain.expected.values.tobytes()


@pytest.mark.parametrize("sea", [ONE, THREE], ids=["one-cascade", "three-cascades"])
@pytest.mark.parametrize("off_node", [False, True], ids=["on-nodes", "between-nodes"])
def test_data_are_honoured_to_rounding_without_noise(off_node, sea):
    shift = 0.37 if off_node else 0.0
    data = ((3.0 + shift, 5.0, 0.1, 0.0), (20.0, 41.0 + shift, -0.08, 0.0), (63.5, 0.2, 0.05, 0))
    system = kriging(sea, points=data, noise=0.0)
    x, y, elevation, _ = np.array(data).T
    for seed in range(3):
        surface = conditioned(system, np.random.default_rng(seed))
        # float32 fields of a few cm: rounding ~1e-8 m
        assert_allclose(surface.elevation_at(x, y), elevation, rtol=0, atol=1e-6)


def test_data_condition_every_frame_and_the_correction_travels():
    # One datum at t = 0.5 s, no noise: the correction is w C(x − x_d, t − t_d), with
    # w = (d − η_u(x_d, t_d)) / C(0, 0): a shifted copy of the space–time covariance.
    x_d, y_d, t_d, d = 10.0, 30.0, 0.5, 0.15
    times = (0.0, 0.5, 2.0)
    system = kriging(ONE, points=((x_d, y_d, d, t_d),), noise=0.0)
    unconditional = free(ONE, np.random.default_rng(2), times)
    tied = conditioned(system, np.random.default_rng(2), times)
    assert tied.elevation_at(x_d, y_d, frame=1) == pytest.approx(d, abs=1e-6)
    c0 = space_time_covariance(ONE)[0, 0]
    weight = (d - float(unconditional.elevation_at(x_d, y_d, frame=1))) / c0
    nodes = np.arange(N) * SPACING
    dx, dy = np.meshgrid(nodes - x_d, nodes - y_d)
    for frame, t in enumerate(times):
        kernel = mode_sum_covariance(ONE, dx.ravel(), dy.ravel(), t - t_d)
        correction = (tied.elevation[frame] - unconditional.elevation[frame]).ravel()
        assert_allclose(correction, weight * kernel, rtol=0, atol=1e-5 * abs(weight) * c0)
    # slopes are corrected too: the slope of the correction is that of the kernel
    tied_slope = tied.cascades[0].slope_x[0]
    assert not np.array_equal(tied_slope, unconditional.cascades[0].slope_x[0])


@pytest.mark.parametrize(
    ("sea", "far"),
    [(ONE, (40.0, 40.0)), (THREE, (49.0, 49.0))],
    ids=["one-cascade", "three-cascades"],
)
def test_draws_have_the_kriging_mean_and_variance(sea, far):
    # Data at two times (0 and 1 s), one between nodes; frames at 0 and 2 s. Over M
    # draws the sample mean is within 5 standard errors sqrt(v/M) of the kriging mean,
    # and the sample variance within 5 sqrt(2/(M-1)) (relative) of the kriging variance
    # (Gaussian sample variance), at test points on the data, between, and far away,
    # with the covariance of the summed cascades.
    noise, draws, times = 0.01, 1500, (0.0, 2.0)
    data = [(8.0, 8.0, 0.0, 0.12), (12.3, 9.0, 0.0, -0.05), (9.0, 14.0, 1.0, 0.03)]
    system = kriging(sea, points=points_of(data), noise=noise)
    locations = [(8.0, 8.0, 0), (10.0, 11.0, 0), (10.0, 11.0, 1), (*far, 0)]
    rng = np.random.default_rng(11)
    values = np.empty((draws, len(locations)))
    for m in range(draws):
        surface = conditioned(system, rng, times)
        for p, (x, y, frame) in enumerate(locations):
            values[m, p] = surface.elevation_at(x, y, frame=frame)
    prior = point_covariance((0, 0, 0), (0, 0, 0), sea)
    if sea is THREE:  # the cascades hold the spectrum (its finest patch alone: 64 %)
        assert prior > 0.95 * SEA.variance()
    for p, (x, y, frame) in enumerate(locations):
        mean, variance = kriging_oracle(data, noise, (x, y, times[frame]), sea)
        assert abs(values[:, p].mean() - mean) < 5 * np.sqrt(variance / draws)
        assert abs(values[:, p].var(ddof=1) / variance - 1) < 5 * np.sqrt(2 / (draws - 1))
    # at the first datum the spread is below the noise; far away it is the prior's
    assert kriging_oracle(data, noise, (8.0, 8.0, 0.0), sea)[1] < noise**2
    far_mean, far_variance = kriging_oracle(data, noise, (*far, 0.0), sea)
    assert far_variance > 0.99 * prior and abs(far_mean) < 0.05 * abs(data[0][3])
    spread = values[:, 3].var(ddof=1)
    assert abs(spread / prior - 1) < 5 * np.sqrt(2 / (draws - 1))


@pytest.mark.parametrize(
    ("conditioning", "surface", "message"),
    [
        ({"points": [[70.0, 3.0, 0.1]]}, {}, "off the sea's coarsest patch"),
        ({"points": [[-1.0, 3.0, 0.1]]}, {}, "x=-1 m, y=3 m"),
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
    # built to render, where the error is the input's
    with pytest.raises(SceneError, match=r"surface\.conditioning\.points: .*ill-conditioned"):
        surface_kriging(scene.surface, scene_sea(scene))


def test_singular_systems_name_the_redundant_points():
    with pytest.raises(ValueError, match=r"points 1 \(2, 3 m, t=0 s\), 2 \(2, 3 m, t=0 s\)"):
        kriging(
            ONE,
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
    eta = ds.surface_elevation.isel(frame=0)
    assert float(eta.sel(sx=5.0, sy=6.0)) == pytest.approx(0.1, abs=1e-6)
    between = eta.sel(sx=[30.0, 31.0], sy=20.0).mean()  # bilinear at x = 30.5
    assert float(between) == pytest.approx(-0.05, abs=1e-6)


@pytest.mark.parametrize(
    ("conditioning", "csv", "message"),
    [
        ("{file: data/points.csv}", "x,y,z\n1,2,3\n", "header"),
        ("{file: data/points.csv}", "x,y,elevation\n1,2\n", "line 2: expected 3"),
        ("{file: data/points.csv}", "x,y,elevation\n1,2,nan\n", "finite"),
        ("{file: data/points.csv}", "x,y,elevation\n", "no points"),
        ("{file: data/missing.csv}", "x,y,elevation\n1,2,3\n", "No such file"),
        ("{file: data/points.csv, points: [[1, 2, 3]]}", "x,y,elevation\n1,2,3\n", "not both"),
        ("{file: data/points.csv}", "x,y,elevation\n99,2,0.1\n", "off the sea's coarsest patch"),
    ],
    ids=["header", "short-row", "nan", "empty", "missing", "both", "off-grid"],
)
def test_bad_csv_files_are_refused(tmp_path, conditioning, csv, message):
    path = write_sweep(tmp_path, conditioning, csv)
    with pytest.raises(InputError, match=r"scene.*surface\.conditioning") as error:
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
