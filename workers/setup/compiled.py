"""A scene compiled once: `Setup`, every value the renderers read of a scene, typed.

`workers.setup.builder.scene_setup` builds it from a `Scene` (cached by the scene); below
`workers.render` nothing else reads the scene. Angles are in radians, converted once by
the builder. Per frame, `workers.setup.sensor.sensor_at` places the camera and the laser.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from workers.backends.backend import Backend
from workers.optics.phases.base import PhaseTable, phase_named
from workers.optics.water import WaterOptics
from workers.sea.cascades import Sea, subgrid_slope_covariance
from workers.sea.conditioning import Kriging
from workers.sea.surface import NUMPY, Surface, draw
from workers.settings.seeds import SampleSeed
from workers.setup.gates import gate_gains
from workers.setup.geometry import PlaneGrid
from workers.targets.base import shape_named
from workers.targets.impostor import Impostor

__all__ = ["Photons", "Setup"]


@dataclass(frozen=True)
class Photons:
    """What the Monte Carlo renderer's photons are given (`Transport`'s values).

    Attributes
    ----------
    phase_function : str
        The registered phase function they scatter with (`workers.optics.phases`; one
        defined over the sphere).
    photons : int
        Photons a frame [1].
    batches : int
        Independent batches a frame [1].
    max_scattering : int or None
        Most scatterings a photon (None: no limit) [1].
    """

    phase_function: str
    photons: int
    batches: int
    max_scattering: int | None


@dataclass(frozen=True, eq=False)
class Setup:
    """What every frame of every sample of a scene shares, compiled once from the scene.

    Equal only to itself (its caches, `workers.fast.planes.frame_geometry`'s among them,
    are keyed by identity: `workers.setup.builder.scene_setup` returns one per scene).

    Attributes
    ----------
    water : WaterOptics
        The water's optics.
    sea : Sea or None
        The sea's cascades (None: flat).
    kriging : callable
        The kriging system of the sea's measured elevations, built on first call (cached;
        None without measurements).
    max_elevation : float or None
        The largest elevation a drawn sea is scaled down to [m] (None: as drawn).
    surface_spacing : float or None
        The finest cascade's grid spacing [m] (None: a flat sea).
    gates : tuple of (float, float)
        Each gate's top and bottom depth under a flat sea at nadir [m].
    reference_depths : tuple of float
        Each gate's backscatter centroid, the depth of its plane [m].
    reflectances : tuple of float
        Each gate's effective Lambertian reflectance on its plane [1].
    scale : float
        The factor taking the raw signal to photoelectrons (or white-plane units).
    refracted_nadir : float
        The central ray's angle in the water [rad].
    secant : float
        1 / cos `refracted_nadir` [1].
    altitude : float
        The platform's height over mean sea level at t = 0 [m].
    nadir, azimuth : float
        The central ray's angle from the downward vertical and compass azimuth [rad].
    velocity : tuple of float
        The platform's velocity (x, y, z) [m/s].
    interval : float
        Time between frames [s].
    frames : int
        Frames a sample [1].
    pixels : int
        Pixels per side of an image [1].
    field_of_view : float
        The receiver's full field [rad].
    receiver_aperture : float
        The receiver's aperture diameter [m].
    beam : str
        The laser's beam, ``divergent`` or ``parallel``.
    laser_field_of_view : float
        The laser's full field [rad].
    rays : int
        Rays per side of the laser lattice [1].
    pixel_pitch_rays : int
        Rays per side of a lattice at the pixels' pitch (`rays`' default) [1].
    psf_truncation : float or None
        The spread's truncation (`workers.settings.sea.Water.psf_truncation`).
    target : object
        The target (its settings: ``shape``, ``radius`` [m], ``depth`` [m],
        ``reflectance``, ``shading``; the target-shape plug-in at merge).
    target_centre : tuple of float
        World (x, y) of the target's centre: as given, or on the central ray [m].
    photons : Photons
        What the Monte Carlo renderer's photons are given.
    """

    water: WaterOptics
    sea: Sea | None
    kriging: Callable[[], Kriging | None]
    max_elevation: float | None
    surface_spacing: float | None
    gates: tuple[tuple[float, float], ...]
    reference_depths: tuple[float, ...]
    reflectances: tuple[float, ...]
    scale: float
    refracted_nadir: float
    secant: float
    altitude: float
    nadir: float
    azimuth: float
    velocity: tuple[float, float, float]
    interval: float
    frames: int
    pixels: int
    field_of_view: float
    receiver_aperture: float
    beam: str
    laser_field_of_view: float
    rays: int
    pixel_pitch_rays: int
    psf_truncation: float | None
    target: object
    target_centre: tuple[float, float]
    photons: Photons

    def surface(self, seed: SampleSeed, times, *, backend: Backend = NUMPY) -> Surface | None:
        """The sample's sea at `times` [s]: drawn, conditioned on the scene's data (None: flat).

        Cascade c draws from ``seed.surface_rng(c)``, the measurement noise of the
        conditioning from cascade 0's stream after its normals. The modes are drawn and
        conditioned on the host (the same sea on every backend), then evolved and
        transformed on `backend` (`workers.sea.surface.Modes.surface`), where the returned
        `Surface` keeps its fields and answers at points.
        """
        if self.sea is None:
            return None
        rngs = [seed.surface_rng(c) for c in range(len(self.sea.patches))]
        modes = draw(self.sea, rngs)
        conditioning = self.kriging()  # cached; built to render
        if conditioning is not None:
            modes = conditioning.condition(modes, rngs[0])
        return modes.surface(times, max_elevation=self.max_elevation, backend=backend)

    def gate_gain(self, excess, gate: int):
        """`workers.setup.gates.gate_gain` of this scene's gate number `gate` [1]."""
        return self.gate_gains(excess, (gate,))[0]

    def gate_gains(self, excess, gates=None):
        """`workers.setup.gates.gate_gain` of this scene's gates (default all), in a list [1]."""
        gates = range(len(self.gates)) if gates is None else gates
        return gate_gains(
            excess,
            diffuse_attenuation=self.water.diffuse_attenuation,
            refractive_index=self.water.refractive_index,
            secant=self.secant,
            slabs=[(*self.gates[g], self.reference_depths[g]) for g in gates],
        )

    def platform_position(self, time: float) -> np.ndarray:
        """Platform position (x, y, z) at `time` [s] [m]: over the origin at t = 0, then moving."""
        reach = self.altitude * np.tan(self.nadir)
        start = np.array(
            [-reach * np.sin(self.azimuth), -reach * np.cos(self.azimuth), self.altitude]
        )
        return start + time * np.asarray(self.velocity, dtype=float)

    def phase_table(self) -> PhaseTable:
        """The table of the phase function the photons scatter with (cached).

        Built for the water's b_b/b (rounded to 12 digits) and θ0
        (`workers.optics.phases.base.PhaseFunction.table`).
        """
        fraction = self.water.backscatter / max(self.water.scattering, 1e-300)
        if self.water.scattering == 0.0:
            fraction = 0.0183  # no scattering: the shape is never used
        phase = phase_named(self.photons.phase_function).for_water(
            backscatter_fraction=round(fraction, 12), theta0=self.water.theta0
        )
        return phase.table()

    def impostor(self, grid: PlaneGrid) -> Impostor:
        """The target rasterised on `grid` (`workers.targets.base.TargetShape.impostor`)."""
        t = self.target
        return shape_named(t.shape).impostor(
            grid=grid, target=t, centre=self.target_centre, refracted_nadir=self.refracted_nadir
        )

    def gated_share(self, grid: PlaneGrid, top, bottom, *, on, delays, shares):
        """The target shape's `gated_share` on `grid`, or None.

        None where the shape has none (`workers.targets.base.TargetShape.gated_share`: a
        disk, or the paper's shading): a cell is then in a gate or not, by its line of
        sight's depth.
        """
        t = self.target
        return shape_named(t.shape).gated_share(
            grid=grid,
            target=t,
            centre=self.target_centre,
            refracted_nadir=self.refracted_nadir,
            top=top,
            bottom=bottom,
            on=on,
            delays=delays,
            shares=shares,
        )

    def subgrid_sway(self, grid: PlaneGrid, *, distance: float) -> np.ndarray | None:
        r"""Where the sub-grid slopes move a line `distance` below where they tilt it.

        Parameters
        ----------
        grid : PlaneGrid
            The plane whose axes the covariance is on.
        distance : float
            The water path d below the tilt [m]: a plane's depth for the lines of sight.

        Returns
        -------
        ndarray or None
            The (u, v) covariance [m²] of :math:`(1 - 1/n)\,d\,\mathbf s`, s the slopes
            below the finest grid (`workers.sea.cascades.subgrid_slope_covariance`): a
            facet of slope s tilts a line refracted into the water by about −(1 − 1/n)s.
            None over a flat sea.

        Notes
        -----
        A pixel looks through many cells of the finest grid, each with its own sub-grid
        slope (`workers.sea.surface.SubgridSlopes`), so it sees a point of the target
        blurred by this Gaussian; its one line of sight would instead read the target at
        one random displacement, the same one that sets its mask
        (`workers.dataset.labels.target_mask`), and keep the target's light inside the
        mask. The target's light and the view it stops are therefore read along the lines
        through the resolved sea and blurred by it, as the Monte Carlo renderer's way up
        does (docs/model.md §9). The scene's covariance is used (`max_elevation`'s
        rescaling of a sample is not applied to it).
        """
        if self.sea is None:
            return None
        reach = (1.0 - 1.0 / self.water.refractive_index) * distance
        return reach**2 * grid.on_axes(subgrid_slope_covariance(self.sea))
