"""A frame's sensor: the camera, the laser lattice and the gates' timing at a frame.

`sensor_at` places them at a frame of a scene's compiled setup
(`workers.setup.compiled.Setup`); the pixels' flat-sea lines of sight and the frame's
plane grids follow as the sensor's methods. The model is in ``docs/model.md``.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from workers.setup.compiled import Setup
from workers.setup.gates import central_paths, sight_lines, slab_bounds
from workers.setup.geometry import LaserRays, PinholeCamera, PlaneGrid, flat_sea_point

__all__ = ["Sensor", "lattice_offset", "sensor_at"]


@dataclass(frozen=True)
class Sensor:
    """Camera, laser and the flat-sea gate timing of one frame (no plane yet).

    Attributes
    ----------
    position : ndarray
        The platform's position (x, y, z) [m].
    camera : PinholeCamera
        The receiver's camera.
    laser_fov : float
        The laser's full field [rad].
    laser_rays : int
        Rays per side of the laser lattice [1].
    reference_range : float
        The slant range of the central ray at the first frame [m].
    lattice : tuple of ndarray
        The laser lattice's rays, (origins, directions, ...) (`LaserRays.central`).
    paths : ndarray
        Each gate's opening and closing path lengths along the central ray [m].
    offset : float
        The lattice's shift from the pixels' lines (`lattice_offset`) [steps].
    refractive_index : float
        The water's refractive index [1].
    """

    position: np.ndarray
    camera: PinholeCamera
    laser_fov: float
    laser_rays: int
    reference_range: float
    lattice: tuple
    paths: np.ndarray
    offset: float
    refractive_index: float

    @property
    def central_air(self) -> float:
        """Air path of the central ray to mean sea level [m]."""
        return float(self.position[2] / np.cos(self.camera.nadir))

    def lines_of_sight(self, grid: PlaneGrid, cells=None):
        """Air path [m] and in-water cosine of the flat-sea line of sight to each cell.

        Of every cell of `grid`, or of its flat indices `cells`
        (`workers.setup.gates.sight_lines`).
        """
        x, y = grid.cell_centres()
        if cells is not None:
            x, y = x.ravel()[cells], y.ravel()[cells]
        return sight_lines(
            position=self.position,
            x=x,
            y=y,
            depth=grid.depth,
            refractive_index=self.refractive_index,
        )

    def gate_bounds(self, sight, paths):
        """Gated depth bounds (top, bottom) [m] of a gate's `paths` [m] along `sight`.

        `sight` the lines of sight (`lines_of_sight`); `workers.setup.gates.slab_bounds`.
        """
        air, cos_water = sight
        return slab_bounds(
            paths=paths, air=air, cos_water=cos_water, refractive_index=self.refractive_index
        )

    def central_point(self, depth: float) -> np.ndarray:
        """World (x, y) where the lattice's central ray meets `depth` under a flat sea [m]."""
        origins, directions = self.lattice
        return flat_sea_point(
            origin=origins[:1],
            direction=directions[:1],
            depth=depth,
            refractive_index=self.refractive_index,
        )[0, :2]

    def fine_grid(self, depth: float, *, guard: int, multiple: int) -> PlaneGrid:
        """The camera's fine plane grid at `depth` [m], `guard` cells wider on each side."""
        return PlaneGrid.covering(
            camera=self.camera,
            lattice=self.lattice,
            depth=depth,
            refractive_index=self.refractive_index,
            guard=guard,
            multiple=multiple,
        )

    def sight_grid(self, depth: float, *, guard: int) -> PlaneGrid:
        """A grid at `depth` [m] whose nodes are the pixels' flat-sea lines, a pixel apart.

        What is read per pixel at its own scale, whatever the laser lattice (`laser.rays`
        and its offset, `lattice_offset`): the target's mask and the view the target
        stops, each cell holding its pixel's footprint. `guard` cells on every side.
        """
        camera, n_w = self.camera, self.refractive_index
        lattice = LaserRays.central(
            position=self.position,
            rotation=camera.rotation,
            beam="divergent",
            field_of_view=camera.field_of_view,
            rays=camera.pixels,
            reference_range=self.reference_range,
        )
        grid = PlaneGrid.covering(
            camera=camera, lattice=lattice, depth=depth, refractive_index=n_w, guard=guard
        )
        line = flat_sea_point(
            origin=lattice[0][:1], direction=lattice[1][:1], depth=depth, refractive_index=n_w
        )[0, :2]
        origin = np.asarray(grid.origin, dtype=float)
        for axis, spacing in ((grid.axis_u, grid.spacing_u), (grid.axis_v, grid.spacing_v)):
            steps = (line - origin) @ axis / spacing
            origin = origin + (steps - np.round(steps)) * spacing * np.asarray(axis)
        return replace(grid, origin=(float(origin[0]), float(origin[1])))


def sensor_at(setup: Setup, frame: int, *, rays: int | None = None) -> Sensor:
    """Camera, laser and gate timing of `frame` (no plane yet).

    `rays` per side of the laser lattice: the scene's (`Setup.rays`) when None.
    """
    rays = setup.rays if rays is None else rays
    position = setup.platform_position(frame * setup.interval)
    camera = PinholeCamera(
        position=tuple(position),
        nadir=setup.nadir,
        azimuth=setup.azimuth,
        field_of_view=setup.field_of_view,
        pixels=setup.pixels,
    )
    laser_fov = setup.laser_field_of_view
    reference_range = setup.altitude / np.cos(setup.nadir)
    offset = lattice_offset(
        pixels=setup.pixels,
        field_of_view=camera.field_of_view,
        rays=rays,
        laser_field_of_view=laser_fov,
    )
    lattice = LaserRays.central(
        position=position,
        rotation=camera.rotation,
        beam=setup.beam,
        field_of_view=laser_fov,
        rays=rays,
        reference_range=reference_range,
        offset=offset,
    )
    paths = central_paths(
        altitude=float(position[2]),
        nadir=setup.nadir,
        refractive_index=setup.water.refractive_index,
        gates=setup.gates,
    )
    return Sensor(
        position=position,
        camera=camera,
        laser_fov=laser_fov,
        laser_rays=rays,
        reference_range=reference_range,
        lattice=lattice,
        paths=paths,
        offset=offset,
        refractive_index=setup.water.refractive_index,
    )


def lattice_offset(*, pixels, field_of_view, rays, laser_field_of_view) -> float:
    """Shift of the laser lattice that keeps it farthest from the pixels' lines [steps].

    Parameters
    ----------
    pixels : int
        Pixels per side of the image.
    field_of_view : float
        The receiver's full field [rad].
    rays : int
        Rays per side of the laser lattice across `laser_field_of_view`.
    laser_field_of_view : float
        The laser's full field [rad].

    Returns
    -------
    float
        The shift in [0, 1) of a ray step along both tangent axes
        (`workers.setup.geometry.LaserRays.from_platform`'s `offset`).

    Notes
    -----
    A pixel's line of sight that is a laser ray reads its own ray's light wherever the
    sea sends it, whose share of the pixel's bilinear read does not shrink with the ray
    count: the double passage is overestimated by a fixed bias (docs/model.md §3). The
    lines' positions in the lattice, modulo a step, are sorted and the lattice is moved
    to the middle of their largest gap: midway between the lines when the rays share
    their pitch (the default) or an odd multiple of it, and at the lines' midpoints for
    an even multiple.
    """
    pixel_step = 2.0 * np.tan(0.5 * field_of_view) / pixels
    ray_step = 2.0 * np.tan(0.5 * laser_field_of_view) / rays
    lines = (np.arange(pixels) + 0.5 - 0.5 * pixels) * pixel_step / ray_step + 0.5 * rays - 0.5
    phases = np.unique(np.round(np.mod(lines, 1.0), 9))
    gaps = np.diff(np.append(phases, phases[0] + 1.0))
    widest = int(np.argmax(gaps))
    return float(np.mod(phases[widest] + 0.5 * gaps[widest], 1.0))
