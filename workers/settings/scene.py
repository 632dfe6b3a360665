"""The parameters of one sample: a frozen, validated description of the scene.

Every field declares its unit as data (`workers.settings.section.units`), a default and a valid
range. Angles that a person types are in degrees and named ``*_deg``; everything else is SI
(metres, seconds, 1/m). The nesting is what sweep files address with dotted paths
(``target.depth``; see the README's sweep file). The sections `Scene` nests are in
`workers.settings.sea` (surface, water, target) and `workers.settings.instrument` (platform,
laser, receiver,
radiometry, noise, sequence).
"""

from __future__ import annotations

import math

import numpy as np
from pydantic import Field, model_validator

from workers.optics.phases.base import phase_named
from workers.sea.conditioning import check_points
from workers.sea.described import surface_patches
from workers.settings.instrument import Laser, Noise, Platform, Radiometry, Receiver, Sequence
from workers.settings.sea import SurfaceSpec, Water
from workers.settings.section import Section, units
from workers.settings.target import Target
from workers.settings.transport import Transport

__all__ = ["Scene", "footprint_span", "laser_rays"]

MAX_RAYS = 4096
"""Most laser rays per side (16.8 million rays)."""

MAX_PLANE_CELLS = 8192
"""Most cells per side of an in-water plane (a 0.5 GiB float64 splat)."""


def laser_rays(*, rays, pixels, field_of_view_deg, laser_field_of_view_deg) -> int:
    """Rays per side of the laser lattice: `rays`, or by default the pixels' pitch.

    The one home of `laser.rays`' default, which the scene (`Scene.laser_rays`) and the
    service's memory estimate (`service.sweep.memory_estimate`, from raw values) read.

    Parameters
    ----------
    rays : int or None
        `laser.rays` [1]; None: the default.
    pixels : int
        Pixels per side of the image [1].
    field_of_view_deg : float
        The receiver's full field [deg].
    laser_field_of_view_deg : float or None
        The laser's full field [deg]; None: the receiver's.

    Returns
    -------
    int
        `rays`, or the rays per side of a lattice at the pixels' angular pitch over the
        laser's field, at least 8.
    """
    if rays is not None:
        return rays
    receiver = math.tan(0.5 * math.radians(field_of_view_deg))
    laser = math.tan(0.5 * math.radians(laser_field_of_view_deg or field_of_view_deg))
    return max(8, round(pixels * laser / receiver))


def footprint_span(*, altitude, nadir, azimuth, field_of_view):
    r"""Longest stretch of the receiver's footprint along the sea grid's x or y axis [m].

    Parameters
    ----------
    altitude : float
        Height of the pinhole above mean sea level [m].
    nadir : float
        Angle of the central ray from the downward vertical [rad].
    azimuth : float
        Compass azimuth of the central ray, clockwise from north (+y) [rad].
    field_of_view : float
        Full opening α of the square field [rad].

    Returns
    -------
    float
        The longest chord of the footprint parallel to x or to y [m]; ``inf`` if the
        field reaches the horizon.

    Notes
    -----
    The footprint is the quadrilateral where the corner rays of the square field,
    :math:`\mathbf b + \tan(\alpha/2)(\pm\mathbf r \pm \mathbf u)` with the boresight
    **b**, the image's right **r** and its up **u**, meet z = 0 (exact at any nadir
    angle, unlike the paper's L1 of `workers.setup.geometry.footprint_length`). A periodic sea
    of period P repeats inside the image when two points of the footprint lie P apart
    along x or y, i.e. when a chord along x or y is longer than P; for a convex polygon
    the longest such chord passes through a vertex. At nadir with azimuth 0 this is the
    side :math:`2h\tan(\alpha/2)`; a footprint turned by 45° holds a chord √2 longer.
    """
    half = math.tan(0.5 * field_of_view)
    sin_n, cos_n = math.sin(nadir), math.cos(nadir)
    sin_a, cos_a = math.sin(azimuth), math.cos(azimuth)
    boresight = np.array([sin_n * sin_a, sin_n * cos_a, -cos_n])
    right = np.array([cos_a, -sin_a, 0.0])
    up = np.array([cos_n * sin_a, cos_n * cos_a, sin_n])
    corners = []
    for a, b in ((1, 1), (1, -1), (-1, -1), (-1, 1)):
        ray = boresight + half * (a * right + b * up)
        if ray[2] >= 0:
            return math.inf
        corners.append(altitude / -ray[2] * ray[:2])
    corners = np.array(corners)
    longest = 0.0
    for axis in (0, 1):
        along, level = corners[:, axis], corners[:, 1 - axis]
        start, end = np.roll(along, -1), np.roll(level, -1)
        for height in level:
            crossing = (level - height) * (end - height) <= 0
            with np.errstate(divide="ignore", invalid="ignore"):
                t = np.where(end != level, (height - level) / (end - level), 0.0)
            points = np.concatenate(
                [
                    (along + t * (start - along))[crossing & (end != level)],
                    along[level == height],
                ]
            )
            longest = max(longest, float(points.max() - points.min()))
    return longest


class Scene(Section):
    """Everything that defines one sample (except its random seed)."""

    surface: SurfaceSpec = SurfaceSpec()
    water: Water = Water()
    target: Target = Target()
    platform: Platform = Platform()
    laser: Laser = Laser()
    receiver: Receiver = Receiver()
    radiometry: Radiometry = Radiometry()
    noise: Noise = Noise()
    sequence: Sequence = Sequence()
    transport: Transport = Transport()
    save_surface: bool = Field(
        False,
        description="Store the surface elevation of every frame with the sample.",
        json_schema_extra=units("1"),
    )

    @property
    def laser_rays(self) -> int:
        """Rays per side of the laser lattice: `laser.rays`, or `pixel_pitch_rays`."""
        return self.laser.rays if self.laser.rays is not None else self.pixel_pitch_rays

    @property
    def pixel_pitch_rays(self) -> int:
        """Rays per side of a lattice at the pixels' angular pitch (`laser.rays`' default)."""
        return laser_rays(
            rays=None,
            pixels=self.receiver.pixels,
            field_of_view_deg=self.receiver.field_of_view_deg,
            laser_field_of_view_deg=self.laser.field_of_view_deg,
        )

    @property
    def _receiver_half_width(self) -> float:
        return math.tan(0.5 * math.radians(self.receiver.field_of_view_deg))

    @property
    def _laser_half_width(self) -> float:
        degrees = self.laser.field_of_view_deg or self.receiver.field_of_view_deg
        return math.tan(0.5 * math.radians(degrees))

    @model_validator(mode="after")
    def _bounded_work(self) -> Scene:
        rays = self.laser_rays
        if rays > MAX_RAYS:
            raise ValueError(
                f"laser: {rays} rays per side (the laser field over the receiver's pixel "
                f"pitch) exceeds {MAX_RAYS}; set laser.rays or a narrower laser field"
            )
        cells = 1.25 * rays * self._receiver_half_width / self._laser_half_width
        if cells > MAX_PLANE_CELLS:
            raise ValueError(
                f"laser: the receiver's field would span {cells:.0f} cells of the laser's ray "
                f"lattice (limit {MAX_PLANE_CELLS}); use fewer laser.rays or a wider laser "
                "field"
            )
        return self

    def footprint(self) -> float:
        """Longest chord of the receiver's footprint along x or y at the sequence's top [m].

        A laser wider than the receiver lights sea outside the image, whose repeats the
        image does not show (bar the in-water spread); a narrower one lights less than
        the image shows.
        """
        climb = self.sequence.velocity[2] * self.sequence.interval * (self.sequence.frames - 1)
        return footprint_span(
            altitude=self.platform.altitude + max(climb, 0.0),
            nadir=math.radians(self.platform.nadir_deg),
            azimuth=math.radians(self.platform.azimuth_deg),
            field_of_view=math.radians(self.receiver.field_of_view_deg),
        )

    def without_target(self) -> Scene:
        """The same scene with ``target.shape: none``: its target-free twin.

        The sea, the photons and everything else but the target are the same, so the
        twin's images differ from this scene's by the target alone (`workers.settings.seeds`).
        """
        return self.model_copy(update={"target": self.target.model_copy(update={"shape": "none"})})

    def surface_spacing(self) -> float:
        """Grid spacing of the sea's finest cascade (`SurfaceSpec.finest_spacing`) [m]."""
        return self.surface.finest_spacing(self.footprint())

    @model_validator(mode="after")
    def _footprint_within_sea_patch(self) -> Scene:
        surface = self.surface
        span = self.footprint()
        patches = surface_patches(surface, span=span)  # checked, nothing built
        if patches is None:
            if self.save_surface:
                self.surface_spacing()
            return self
        period = patches[-1]
        if surface.conditioning.points:
            try:  # on the patch, each place and time once; the system is built to render
                check_points(surface.conditioning.points, period=period)
            except ValueError as error:
                raise ValueError(f"surface.conditioning.points: {error}") from None
        if span > period and not surface.allow_repeat:
            climb = self.sequence.velocity[2] * self.sequence.interval * (self.sequence.frames - 1)
            altitude = self.platform.altitude + max(climb, 0.0)
            highest = f"{altitude:g} m at the sequence's top, " if climb > 0 else ""
            raise ValueError(
                f"the receiver's footprint on the sea (platform.altitude "
                f"{self.platform.altitude:g} m, {highest}platform.nadir_deg "
                f"{self.platform.nadir_deg:g}, platform.azimuth_deg "
                f"{self.platform.azimuth_deg:g}, receiver.field_of_view_deg "
                f"{self.receiver.field_of_view_deg:g}) spans {span:.2f} m, wider than the "
                f"coarsest periodic sea patch, {period:.2f} m (surface.grid_size "
                f"{surface.grid_size}, surface.spacing {patches[0] / surface.grid_size:g} m, "
                f"surface.coarse_patches {surface.coarse_patches}): the same waves would "
                "repeat inside the image. Set surface.allow_repeat: true to render it anyway, "
                "or leave surface.coarse_patches null, narrow the field or lower the platform"
            )
        return self

    @model_validator(mode="after")
    def _phase_function_for_the_water(self) -> Scene:
        t, water = self.transport, self.water.coefficients
        users = []  # each renderer's phase function, where it is built for the water's b_b/b
        if t.method == "small_angle":
            users.append(("water.phase_function", self.water.phase_function))
        else:
            users.append(("transport.phase_function", t.phase_function))
        if water["scattering"] == 0:
            return self
        fraction = water["backscatter"] / water["scattering"]
        for field, name in users:
            fractions = phase_named(name).fractions
            if fractions is not None and not fractions[0] <= fraction <= fractions[1]:
                low, high = fractions
                raise ValueError(
                    f"water.backscatter: b_b/b = {fraction:.4g} is outside "
                    f"[{low:.4g}, {high:.4g}], the range {field} {name} can match; "
                    f"change water.backscatter or use {field}: paper"
                )
        return self

    @model_validator(mode="after")
    def _altitude_during_sequence(self) -> Scene:
        climb = self.sequence.velocity[2] * self.sequence.interval * (self.sequence.frames - 1)
        if self.platform.altitude + climb <= 1.0:
            raise ValueError("the platform would reach the sea during the sequence")
        return self
