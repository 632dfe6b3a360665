"""How the fast renderer gates the target's light: by each cell's share, its delay, its depth.

Issue #24 items 4 and 5. The end-to-end checks against photon transport are in
``tests/test_transport_reference.py``; these hold the parts to closed forms.
"""

import numpy as np
import pytest
from numpy.testing import assert_allclose

from workers.fast.delays import DELAY_POINTS, return_delays
from workers.optics.water import WaterOptics
from workers.render import render_arrays
from workers.settings.scene import Scene
from workers.setup.geometry import PlaneGrid
from workers.targets.impostor import disc_cover, gated_share


def square_grid(*, spacing, cells, depth):
    half = 0.5 * (cells - 1) * spacing
    return PlaneGrid(
        depth=depth,
        origin=(-half, half),
        axis_u=(1.0, 0.0),
        axis_v=(0.0, -1.0),
        spacing_u=spacing,
        spacing_v=spacing,
        shape=(cells, cells),
    )


@pytest.mark.parametrize(("top", "bottom"), [(4.88, 9.0), (4.75, 4.9), (5.1, 6.0), (3.0, 4.8)])
def test_a_gate_holds_the_lambertian_return_of_its_annulus(top, bottom):
    # A sphere (r = 0.3 m, centre 5 m) at nadir: the gate [t, b] holds the surface whose
    # chord half-length q = z_c − z_s lies in [z_c − b, z_c − t], an annulus whose
    # Lambertian return ∫ cos i dA = (2π / 3r) (q_hi³ − q_lo³). Cells of 0.07 m (the
    # renderer's at 128 px): each cell's share times its whole return, summed.
    radius, depth, spacing = 0.3, 5.0, 0.07
    grid = square_grid(spacing=spacing, cells=24, depth=depth)
    common = {
        "grid": grid,
        "centre": (0.0, 0.0),
        "radius": radius,
        "refracted_nadir": 0.0,
        "on": np.ones(grid.shape, dtype=bool),
    }
    share = gated_share(
        **common,
        top=np.full(grid.shape, top),
        bottom=np.full(grid.shape, bottom),
        delays=(0.0,),
        shares=(1.0,),
    )
    whole = gated_share(
        **common,
        top=np.full(grid.shape, 0.0),
        bottom=np.full(grid.shape, 99.0),
        delays=(0.0,),
        shares=(1.0,),
    )
    # a return in two halves, one 0.1 m late: the gate holds the mean of the two
    halves = gated_share(
        **common,
        top=np.full(grid.shape, top),
        bottom=np.full(grid.shape, bottom),
        delays=(0.0, 0.1),
        shares=(0.5, 0.5),
    )
    later = gated_share(
        **common,
        top=np.full(grid.shape, top - 0.1),
        bottom=np.full(grid.shape, bottom - 0.1),
        delays=(0.0,),
        shares=(1.0,),
    )
    assert_allclose(halves, 0.5 * (share + later), atol=1e-12)
    x, y = grid.cell_centres()
    _, cosine = disc_cover(u=x, w=-y, cell_u=spacing, cell_w=spacing, radius=radius)
    q_lo, q_hi = (np.clip(depth - z, 0.0, radius) for z in (bottom, top))
    expected = 2 * np.pi / (3 * radius) * (q_hi**3 - q_lo**3)
    # 8-point Gauss-Legendre in u across the annulus' rims, where the integrand has a
    # square-root edge: 0.3 % at most on these cells (the disc alone: exact to 1e-12)
    assert_allclose((share * cosine).sum() * spacing**2, expected, rtol=5e-3, atol=1e-9)
    assert np.all((whole == 1.0) | (cosine == 0.0))


def test_return_delays_are_deterministic_and_grow_with_scattering():
    clear, turbid = (WaterOptics.from_preset(p) for p in ("clear_ocean", "turbid_harbour"))
    geometry = {"path": 5.0, "beam_radius": 2.0, "target_radius": 0.3}
    unscattered, delays = return_delays(clear, **geometry)
    assert (unscattered, delays.tolist()) == (
        return_delays.__wrapped__(clear, **geometry)[0],
        return_delays.__wrapped__(clear, **geometry)[1].tolist(),
    )
    assert delays.shape == (DELAY_POINTS,) and np.all(np.diff(delays) >= 0)
    # without a side step's weight the unscattered share would be e^(-2 b_f l) = 0.70;
    # scattered paths off the target count less, so more of the light is on time
    assert np.exp(-2 * clear.forward_scattering * 5.0) < unscattered < 1.0
    turbid_unscattered, turbid_delays = return_delays(turbid, **geometry)
    assert turbid_unscattered < unscattered and np.median(turbid_delays) > np.median(delays)
    # no scattering: all on time
    still = WaterOptics(absorption=0.2, scattering=0.0, backscatter=0.0)
    assert return_delays(still, **geometry)[0] == 1.0


def test_single_scattering_delays_follow_the_angle_and_the_place():
    # Wells' phase function with θ0 = 0.02 rad, b_f l = 0.05 a leg (single scattering: a
    # second one in 2.5 % of the scattered legs), no side-step weighting (radii of 1e6 m):
    # a scattering at depth u of a leg of l turns it by θ and lengthens it by
    # (l − u)(sec θ − 1), half of which is the return's delay δ. Drawn directly: θ from
    # the inverse of P(θ < x) = (1 − θ0/√(θ0² + x²)) / (1 − θ0/√(θ0² + (π/2)²)) (Wells'
    # s(θ) ∝ (θ0² + θ²)^-3/2 on the renderer's θ ≤ π/2), u uniform, each leg scattered
    # with probability 1 − e^(−b_f l).
    theta0, path, leg = 0.02, 5.0, 0.05
    water = WaterOptics(
        absorption=0.1,
        scattering=leg / path,
        backscatter=0.0,
        phase_function="wells",
        theta0=theta0,
    )
    unscattered, delays = return_delays(water, path=path, beam_radius=1e6, target_radius=1e6)
    assert_allclose(unscattered, np.exp(-2 * leg), atol=4 * np.sqrt(0.1 / 8192))
    rng = np.random.default_rng(1)
    n = 400_000
    top = 1 - theta0 / np.hypot(theta0, 0.5 * np.pi)

    def one_leg():
        scattered = rng.uniform(size=n) < 1 - np.exp(-leg)
        p = rng.uniform(size=n) * top
        theta = theta0 * np.sqrt(1 / (1 - p) ** 2 - 1)
        stretch = (path - rng.uniform(0, path, n)) * (1 / np.cos(np.minimum(theta, 1.5)) - 1)
        return np.where(scattered, stretch, 0.0)

    law = 0.5 * (one_leg() + one_leg())
    late = law[law > 0]
    probabilities = (np.arange(DELAY_POINTS) + 0.5) / DELAY_POINTS
    # the renderer's quantiles come from the ~780 scattered of its 8192 paths: each must
    # lie within the range that 400 draws of that many paths of the law give it
    count = round(8192 * (1 - np.exp(-2 * leg)))
    replicas = np.quantile(rng.choice(late, (400, count)), probabilities, axis=1)
    low, high = replicas.min(axis=1), replicas.max(axis=1)
    assert np.all((delays >= low) & (delays <= high)), (delays, low, high)


def centre_signal(shape, *, radius, top, pixels):
    """Target minus its twin over the 2 × 2 central pixels, in K = 0.2 /m water."""
    scene = Scene.model_validate(
        {
            "surface": {"spectrum": "flat"},
            "water": {
                "preset": None,
                "absorption": 0.2,
                "scattering": 0.001,
                "backscatter": 0.00002,
            },
            "target": {
                "shape": shape,
                "radius": radius if shape == "sphere" else 3.0,
                "depth": top + radius if shape == "sphere" else top,
                "reflectance": 0.5,
            },
            "receiver": {"pixels": pixels, "gates": [[top - 0.5, top + 2 * radius + 0.5]]},
            "radiometry": {"mode": "normalised", "white_plane_photons": 0},
        }
    )
    twin = scene.model_copy(update={"target": scene.target.model_copy(update={"shape": "none"})})
    c = pixels // 2
    images = [
        render_arrays(s, seed=1)["expected"][0, 0, c - 1 : c + 1, c - 1 : c + 1]
        for s in (scene, twin)
    ]
    return (images[0] - images[1]).mean()


@pytest.mark.parametrize(("radius", "pixels"), [(0.3, 128), (1.0, 64), (2.0, 64)])
def test_the_top_of_a_sphere_is_lit_as_a_disk_at_its_depth(radius, pixels):
    # Issue #24 item 5: the beam's light at the top of a sphere (cos i = 1 there) is the
    # light at the sphere's top depth, not at its centre's: its return equals a white
    # disk's at that depth within 1 % (the beam's spread taken at the centre gave 0.981,
    # 0.959, 0.925 for r = 0.3, 1, 2 m from 6 m, K = 0.2 /m: the divergent beam is
    # narrower and brighter above the centre plane).
    ratio = centre_signal("sphere", radius=radius, top=6.0, pixels=pixels) / centre_signal(
        "disk", radius=radius, top=6.0, pixels=pixels
    )
    assert abs(ratio - 1) < 0.01, ratio
