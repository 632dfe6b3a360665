"""Which blocking is right for the shadows over sub-grid facets? A renderer-free brute force.

Issue #36 item 2. A pixel looks through many facets below the sea's grid, each of slope s,
each tilting its straight line in the water by −(1 − 1/n) s: at depth d below a flat
resolved sea the line is displaced by δ(d) = (1 − 1/n) d s. Water scattered at depth z_g
reaches the pixel along such a line, which crosses the target's depth z_t at δ(z_t): the
view is stopped where x + δ(z_t) falls on the target's silhouette, and the laser's light
reaches the point x + δ(z_g) along its own facet's line, stopped where that line crosses
the silhouette (blurred over z_g − z_t). Per pixel and depth, with the same facet s for
both, that is *exact* (straight lines, single scattering, no water blur). Against it:

- *look-up*: the Monte Carlo renderer's (`workers.montecarlo.photons`): the point looked up
displaced
  by δ(z_g), the target's blocking tested along the resolved line through the point
  itself, i.e. at x + δ(z_g) on the target's plane;
- *fast*: the fast renderer's (`workers.fast.shadows.gate_shadow`): the view's share blurred by
  the sway at z_t, the light's share read at the pixel's line (blurred by the laser's
  facets only), their product;
- *swayed*: as *fast*, the light's share also blurred by the view's sway at z_g.

For the issue's scene (clear water, 32 px from 34 m, nadir, a 0.3 m sphere at 5 m, the
ML(DC) gates 3–6, Elfouhaily seas of the test's 3.2 cm grid) it prints the shadow's
contrast over the pixels whose lines cross the silhouette, each gate's depths weighted by
e^(−2cz), per wind. Usage, from the repository root:
``python -m benchmarks.shadow_sway [--facets 2000]``.
"""

import argparse

import numpy as np

from workers.settings.scene import Scene
from workers.setup.builder import scene_setup
from workers.setup.sensor import sensor_at

RADIUS, DEPTH = 0.3, 5.0


def scene(wind: float) -> Scene:
    """The issue's scene over a `wind` [m/s] Elfouhaily sea."""
    return Scene.model_validate(
        {
            "receiver": {"pixels": 32, "field_of_view_deg": 6.7, "gates": "mldc"},
            "platform": {"altitude": 34.0},
            "target": {"shape": "sphere", "radius": RADIUS, "depth": DEPTH, "reflectance": 0.2},
            "surface": {
                "spectrum": "elfouhaily",
                "wind_speed": wind,
                "grid_size": 128,
                "spacing": 0.032,
            },
            "water": {"preset": "clear_ocean"},
        }
    )


def shadows(wind: float, facets: int, rng: np.random.Generator) -> list[tuple[float, float]]:
    """Per gate 3–6, the shadow's contrast over the silhouette's pixels, by each blocking."""
    sc = scene(wind)
    setup = scene_setup(sc)
    grid = sensor_at(setup, 0).sight_grid(DEPTH, guard=2)
    unit = setup.subgrid_sway(grid, distance=1.0)  # covariance of δ at 1 m [m²]
    root = np.linalg.cholesky(unit)
    pitch = grid.spacing_u
    offsets = np.arange(-4, 5) * pitch  # pixels' lines about the sphere's axis (even grid)
    x0, y0 = (a.ravel() + 0.5 * pitch for a in np.meshgrid(offsets, offsets))
    inside = np.hypot(x0, y0) < RADIUS
    x0, y0 = x0[inside], y0[inside]
    view = rng.standard_normal((facets, 2)) @ root.T  # δ per metre, the pixel's facets
    laser = rng.standard_normal((facets, 2)) @ root.T  # the laser's facets
    c = setup.water.attenuation
    out = []
    for top, bottom in sc.receiver.gate_depths[2:]:
        depths = np.linspace(top, bottom, 25)
        weights = np.exp(-2.0 * c * depths)
        kept = {"exact": 0.0, "look-up": 0.0, "fast": 0.0, "swayed": 0.0}
        for z, w in zip(depths, weights, strict=True):
            px = x0[:, None] + z * view[None, :, 0]  # the scattering points
            py = y0[:, None] + z * view[None, :, 1]
            # the laser's light the target stops: its line from the point up to z_t
            lx = px[..., None] + (z - DEPTH) * laser[None, None, :64, 0]
            ly = py[..., None] + (z - DEPTH) * laser[None, None, :64, 1]
            lit = 1.0 - (np.hypot(lx, ly) < RADIUS).mean(axis=-1)
            for name, reach in (("exact", DEPTH), ("look-up", z)):
                bx = x0[:, None] + reach * view[None, :, 0]
                by = y0[:, None] + reach * view[None, :, 1]
                seen = np.hypot(bx, by) >= RADIUS
                kept[name] += w * (seen * lit).mean()
            # the fast renderer: the view's and the light's shares apart, both at the line
            seen = (
                np.hypot(
                    x0[:, None] + DEPTH * view[None, :, 0], y0[:, None] + DEPTH * view[None, :, 1]
                )
                >= RADIUS
            ).mean(axis=1)
            lx = x0[:, None] + (z - DEPTH) * laser[None, :, 0]
            ly = y0[:, None] + (z - DEPTH) * laser[None, :, 1]
            lit = 1.0 - (np.hypot(lx, ly) < RADIUS).mean(axis=1)
            kept["fast"] += w * (seen * lit).mean()
            # the same, the light's share read where the view's facets put the point
            lit = 1.0 - (
                np.hypot(lx + z * view[None, :, 0], ly + z * view[None, :, 1]) < RADIUS
            ).mean(axis=1)
            kept["swayed"] += w * (seen * lit).mean()
        total = weights.sum()
        out.append(
            tuple(kept[name] / total - 1.0 for name in ("exact", "look-up", "fast", "swayed"))
        )
    return out


def main() -> None:
    """Print the blockings' shadows and their ratios per wind and gate."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--facets", type=int, default=2000)
    args = parser.parse_args()
    rng = np.random.default_rng(7)
    print("wind  gate  exact   look-up  fast    swayed  exact/look-up  fast/exact  swayed/exact")
    for wind in (1.0, 5.0, 10.0):
        for gate, (exact, lookup, fast, swayed) in enumerate(
            shadows(wind, args.facets, rng), start=3
        ):
            shares = f"{exact:6.3f}  {lookup:7.3f}  {fast:6.3f}  {swayed:6.3f}"
            ratios = f"{exact / lookup:13.2f}  {fast / exact:10.2f}  {swayed / exact:12.2f}"
            print(f"{wind:4.0f}  {gate:4d}  {shares}  {ratios}")


if __name__ == "__main__":
    main()
