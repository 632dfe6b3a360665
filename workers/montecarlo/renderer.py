"""The Monte Carlo renderer: gated images by photon transport through the same rough sea.

`render_frame` renders one frame of a sample as `workers.render` does, with the same sea
realisation, laser, receiver, target, water, gates and radiometry, but carries the light
by photon transport (`workers.montecarlo.photons`) instead of the small-angle spread:

1. The pixels' corner lines of sight (the pinhole through each pixel's corners) meet the
   real surface and refract at each one's facet, slopes below the grid included
   (`workers.setup.interface.through_surface`); the in-water lines, split into two triangles a
   pixel, say which pixels see a point in the water and through how small a cross-section.
2. Photons leave the laser with the Gaussian beam's profile (`workers.setup.geometry.LaserRays`:
   I0 = J e^(-r²/a²) on the cross-section at the reference range, J = 1, so the beam holds
   πa²), meet the surface, refract at their facet and carry its Fresnel transmittance.
3. In the water each photon is followed (`workers.montecarlo.photons.transport`); every scattering
and
   every reflection off the target sends its local estimate to the pixels that see it, in
   each gate whose window holds the path's total optical length.
4. The photons are split into `Transport.batches` independent batches: the image is their
   mean, its standard error their spread over √batches; both are scaled to photoelectrons as
   the fast renderer's are (`workers.setup.compiled.Setup.scale`).

The model and its approximations are in ``docs/model.md`` §9.
"""

from __future__ import annotations

import dataclasses
import itertools
import math
from dataclasses import dataclass

import numpy as np

from workers.dataset.labels import target_mask
from workers.montecarlo.photons import TALLIES, transport
from workers.montecarlo.records import (
    Gates,
    Limits,
    Lookup,
    Medium,
    Phase,
    Point,
    Rays,
    Scenery,
    Sea,
    as_rays,
)
from workers.montecarlo.sightlines import build_lookup
from workers.optics.phases.base import PhaseTable
from workers.sea.surface import Surface
from workers.settings.seeds import SampleSeed
from workers.setup.compiled import Setup
from workers.setup.interface import through_surface
from workers.setup.sensor import Sensor, sensor_at
from workers.targets.base import TargetShape, shape_named

__all__ = [
    "ANGULAR_BIAS",
    "BIAS_SCATTERINGS",
    "LAUNCH_CHUNK",
    "LOOKUP_ENTRIES",
    "MASK_LINES",
    "MAX_SUBDIVISION",
    "SLAB_THICKNESS",
    "TARGET_BIAS",
    "FrameTransport",
    "biasing_share",
    "phase_record",
    "pupil_points",
    "render_frame",
    "sight_subdivision",
]

ANGULAR_BIAS = 0.2
"""Share of scatterings drawn about the way to the receiver (angular biasing, weighted).

A photon's next local estimate is large when it travels almost straight at the receiver
(the phase function's forward peak); drawn from the phase function alone, such directions
are rare and their estimates huge. With this share drawn about the direction to the
receiver and every direction weighted by p / ((1 − ε)p + ε p_receiver) (one-sample
multiple importance sampling), they are frequent and small. Measured on coastal water,
64 px, 2·10⁵ photons: the standard error of the deeper gates' means falls 3–14 times
against ε = 0, the first gate's alike."""

TARGET_BIAS = 0.5
"""Share of reflections off the target drawn about the way to the receiver (weighted).

A Lambertian reflection sends a photon in a cosine-distributed direction; the next
scattering's local estimate is the phase function at the angle between that direction and
the way to the receiver, which its forward peak (about θ^-0.93 below 1 mrad for the
Fournier–Forand fits) makes huge for the rare photons reflected almost straight at it: the
target's light was heavy-tailed (coastal water, the contrast in a gate whose edge cuts a
0.3 m sphere: 0.42-3.62 over 8 seeds of 10⁶ photons, now 1.36-1.79). With this share
drawn from the phase function about the way to the receiver and every direction weighted
by (cos/π) / ((1 − ε) cos/π + ε p_receiver) (one-sample multiple importance sampling, as
for the scatterings), such directions are frequent and light (docs/model.md §9)."""

BIAS_SCATTERINGS = 5.0
"""Scatterings along a path up to which the full `ANGULAR_BIAS` is kept (`biasing_share`)."""

SLAB_THICKNESS = 0.25
"""Thickness of the horizontal slabs in which the lines of sight are bucketed [m] (least)."""

LOOKUP_ENTRIES = 16_000_000
"""Slabs × cells at most in the lines' lookup: thicker slabs beyond (about 64 MB a frame)."""

LAUNCH_CHUNK = 1 << 20
"""Photons launched through the surface at a time (their arrays: 64 MiB)."""

MASK_LINES = 4
"""Lines of sight per pixel side that measure the share of a pixel the target covers."""

MAX_SUBDIVISION = 16
"""Most lines of sight per pixel side (`sight_subdivision`)."""


def phase_record(table: PhaseTable) -> Phase:
    """The kernels' `workers.montecarlo.records.Phase` of a `PhaseTable` (logs, float64).

    A value of 0 (`workers.optics.phases.paper.Paper` backward with b_b = 0) is logged as the
    smallest normal float64's, ln 2.2e-308 = −708, so that interpolation stays finite.
    """
    tiny = np.finfo(np.float64).tiny
    return Phase(
        log_theta0=float(table.log_theta0),
        log_step=float(table.log_step),
        log_values=np.ascontiguousarray(np.log(np.maximum(table.values, tiny)), dtype=np.float64),
        quantiles=np.ascontiguousarray(table.quantiles, dtype=np.float64),
    )


@dataclass(frozen=True)
class FrameTransport:
    """One frame's photon transport: what it rendered and the energy it accounted for.

    Attributes
    ----------
    expected : ndarray, shape (G, P, P)
        Mean image over the batches, in the scene's units (as the fast renderer's), float32.
    stderr : ndarray, shape (G, P, P)
        Its Monte Carlo standard error (the batches' standard deviation / √batches), float32.
    mask : ndarray, shape (P, P)
        The target's mask (`workers.dataset.labels.target_mask`), uint8.
    tallies : dict
        `workers.montecarlo.photons.TALLIES`, the batches' mean [raw power units].
    """

    expected: np.ndarray
    stderr: np.ndarray
    mask: np.ndarray
    tallies: dict


def render_frame(
    setup: Setup,
    surface: Surface | None,
    frame: int,
    seed: SampleSeed,
    *,
    bias=None,
    reflection_bias=TARGET_BIAS,
    pupil=False,
    subgrid_up="blur",
):
    """Render one frame by photon transport.

    Parameters
    ----------
    setup : Setup
        The scene's setup (`workers.setup.builder.scene_setup`).
    surface : Surface or None
        The sample's sea (None: flat).
    frame : int
        Frame index.
    seed : SampleSeed
        The sample's seeds: photons draw from ``seed.photon_key(frame)``.
    bias : float, optional
        Share ε of the scatterings whose direction is drawn about the way to the receiver
        (0: none); default `biasing_share`. Any ε in [0, 1) gives the same expectation.
    reflection_bias : float, optional
        Share of the reflections off the target drawn about the way to the receiver
        (0: none, Lambertian); default `TARGET_BIAS`. Any share in [0, 1) gives the same
        expectation.
    pupil : bool, optional
        Read the light through the receiver's aperture (`Setup.receiver_aperture`) rather
        than its centre: batch b looks from the b-th of `pupil_points` (the pinhole moved
        across the pupil, the pixels' directions kept, the laser at the centre), so the
        batches' mean is the aperture's average (docs/model.md §9). Default False: the
        pinhole at the centre.
    subgrid_up : {"blur", "facet"}, optional
        How the slopes below the sea's grid enter the way up: ``blur`` (default), an
        independent Gaussian blur of the point looked up; ``facet``, the lines of sight
        refracted at the same cell's sub-grid slope as the photons on the way down.

    Returns
    -------
    FrameTransport
    """
    settings = setup.photons
    sensor = sensor_at(setup, frame)
    n_w = setup.water.refractive_index
    pixels = setup.pixels
    sub = sight_subdivision(setup)
    if subgrid_up not in ("blur", "facet"):
        raise ValueError(f"subgrid_up must be 'blur' or 'facet', got {subgrid_up!r}")
    # the corners follow the resolved sea; its sub-grid slopes blur the way up (or facet it)
    subgrid = getattr(surface, "subgrid", None) if subgrid_up == "blur" else None
    resolved = surface if subgrid is None else dataclasses.replace(surface, subgrid=None)
    batches = settings.batches
    shifts = pupil_points(setup.receiver_aperture, batches) if pupil else np.zeros((1, 2))
    receivers = [
        dataclasses.replace(sensor, position=sensor.position + shift @ sensor.camera.rotation[:2])
        for shift in shifts
    ]
    corners = [_sight_lines(r, resolved, frame, n_w, pixels, sub) for r in receivers]
    sea = _sea(surface, frame)
    lowest, highest = _sea_bounds(sea)
    paths = 2.0 * np.asarray(sensor.paths, dtype=np.float64)
    gates = Gates(np.ascontiguousarray(paths[:, 0]), np.ascontiguousarray(paths[:, 1]))
    air_back = float(sensor.position[2]) - highest
    longest = float(gates.closes.max())
    deepest = max((longest - 2.0 * air_back) / (2.0 * n_w) - lowest, 0.0) + 0.5
    top = max(highest, *(float(c.z.max()) for c in corners)) + 0.01
    cells = (pixels * sub) ** 2
    thick = max(SLAB_THICKNESS, (top + deepest) * cells / LOOKUP_ENTRIES)
    slabs = max(1, math.ceil((top + deepest) / thick))
    water = setup.water
    table = setup.phase_table()
    blur = (0.0,) * 5
    if subgrid is not None:
        factor = np.asarray(subgrid.factor, dtype=np.float64).ravel()
        blur = (*(float(f) for f in factor), 1.0 - 1.0 / n_w)
    medium = Medium(
        *(float(v) for v in (n_w, water.attenuation, water.absorption, water.scattering)),
        *blur,
    )
    most = settings.max_scattering or np.iinfo(np.int32).max
    if bias is None:
        bias = biasing_share(scattering=water.scattering, depth=deepest)
    limits = Limits(
        longest=longest,
        air_back=air_back,
        lowest=lowest,
        highest=highest,
        most=int(most),
        bias=float(bias),
        reflection_bias=float(reflection_bias),
    )
    phase = phase_record(table)
    sceneries = []
    for receiver, lines in zip(receivers, corners, strict=True):
        lookup = Lookup(
            top, thick, slabs, sub, *build_lookup(lines, pixels * sub, top, thick, slabs)
        )
        camera = Point(*(float(v) for v in np.asarray(receiver.position, dtype=np.float64)))
        sceneries.append(Scenery(medium, phase, limits, camera, sea, lines, lookup, gates))
    shape = shape_named(setup.target.shape)
    target = shape.record(setup.target, setup.target_centre)
    per_batch = -(-settings.photons // batches)
    rng = seed.photon_rng(frame)
    key = np.uint64(seed.photon_key(frame))
    images = np.zeros((batches, len(setup.gates), pixels, pixels))
    tallies = np.zeros((batches, len(TALLIES)))
    beam_power = math.pi * (sensor.reference_range * math.tan(0.5 * sensor.laser_fov)) ** 2
    for batch, first in itertools.product(range(batches), range(0, per_batch, LAUNCH_CHUNK)):
        count = min(LAUNCH_CHUNK, per_batch - first)
        launch = _launch(
            sensor, setup.beam, surface, frame, n_w, rng, count, beam_power / per_batch
        )
        index = batch * per_batch + first
        scenery = sceneries[batch % len(sceneries)]
        transport(launch, key, index, scenery, target, images[batch], tallies[batch])
    mean = images.mean(axis=0) * setup.scale
    error = images.std(axis=0, ddof=1) / math.sqrt(batches) * setup.scale
    if shape.name == "none":
        mask = np.zeros((pixels, pixels), dtype=np.uint8)
    else:  # the mask's 16 lines a pixel only where there is a target to mask
        centres = _sight_lines(sensor, surface, frame, n_w, pixels, MASK_LINES, centres=True)
        mask = _mask(centres, setup, shape, pixels)
    totals = dict(zip(TALLIES, (tallies.sum(axis=0) / batches).tolist(), strict=True))
    return FrameTransport(mean.astype(np.float32), error.astype(np.float32), mask, totals)


def pupil_points(diameter, count):
    r"""Where the batches look from: `count` points spread evenly over the pupil [m].

    The sunflower layout, point k at radius :math:`\tfrac D2\sqrt{(k + \tfrac12)/K}` and
    angle k times the golden angle, equal areas of the disc each; K = `count`, D =
    `diameter`. All at the centre when D = 0 (the pinhole).

    Parameters
    ----------
    diameter : float
        The aperture's diameter D [m].
    count : int
        K, the number of points (the batches) [1].

    Returns
    -------
    numpy.ndarray
        (K, 2) offsets along the camera's u and v axes [m], float64.
    """
    k = np.arange(count)
    radius = 0.5 * diameter * np.sqrt((k + 0.5) / count)
    angle = k * math.pi * (3.0 - math.sqrt(5.0))
    return np.stack([radius * np.cos(angle), radius * np.sin(angle)], axis=-1)


def biasing_share(*, scattering, depth):
    """The share ε of scatterings drawn about the way to the receiver (angular biasing).

    `ANGULAR_BIAS`, divided by the scatterings a photon's path holds beyond
    `BIAS_SCATTERINGS` (b times the deepest gated depth): each biased draw can cut a
    weight, and along a path of tens of scatterings nearly every photon would take one,
    its weight collapsing to the roulette (in water of b = 10 /m, gates read 10⁻⁶ of
    their value at ε = 0.2).

    Parameters
    ----------
    scattering : float
        Scattering coefficient b [1/m].
    depth : float
        Deepest depth a gated path reaches [m].

    Returns
    -------
    float
        ε [1]: 0.2 in clear and coastal water, 0.035 in turbid harbour water.
    """
    return ANGULAR_BIAS / max(1.0, scattering * depth / BIAS_SCATTERINGS)


def _directions(sensor: Sensor, offsets: np.ndarray) -> np.ndarray:
    """World unit directions of the pinhole through tangent offsets (rows = v, cols = u)."""
    u = offsets[np.newaxis, :]
    v = offsets[:, np.newaxis]
    camera = np.stack(np.broadcast_arrays(u, v, np.ones_like(u * v)), axis=-1)
    camera /= np.linalg.norm(camera, axis=-1, keepdims=True)
    return (camera @ sensor.camera.rotation).reshape(-1, 3)


def sight_subdivision(setup: Setup) -> int:
    """Lines of sight per pixel side S: cells at most the sea's finest spacing wide.

    A pixel's cells must resolve the sea: where the waves focus within a pixel's footprint,
    the light a pixel sees through each part of it is correlated with the laser's light
    through the same part (double passage), and one cell a pixel would average the two
    apart. The cells' width on the mean surface is at most the finest cascade's spacing
    (`Setup.surface_spacing`), on which the resolved slopes vary; 1 over a flat sea.
    Measured over a 5 m/s sea at 64 px (docs/model.md §9): S = 1, 2, 4 give the six gates'
    means within 1.5 % of each other in clear water, S = 2 and 4 within their 2-4 % errors
    in coastal water.

    Parameters
    ----------
    setup : Setup
        The scene's setup.

    Returns
    -------
    int
        S, at least 1, at most `MAX_SUBDIVISION`.
    """
    if setup.surface_spacing is None:
        return 1
    slant = setup.altitude / math.cos(setup.nadir) ** 2
    field = 2.0 * math.tan(0.5 * setup.field_of_view)
    footprint = slant * field / setup.pixels
    return min(MAX_SUBDIVISION, max(1, math.ceil(footprint / setup.surface_spacing)))


def _sight_lines(sensor: Sensor, surface, frame, n_w, pixels, sub, *, centres=False):
    """The pixels' lines of sight in the water, a `Rays` (float64).

    Surface point x, y, z [m], downward unit direction, air path [m], Fresnel
    transmittance (`weight`). With `centres`, through the P² pixel centres; else through
    the corners of S × S cells a pixel, (PS + 1)², row-major (the images' order).
    """
    pitch = 2.0 * math.tan(0.5 * sensor.camera.field_of_view) / (pixels * sub)
    count = pixels * sub
    offsets = (np.arange(count) + 0.5) if centres else np.arange(count + 1)
    directions = _directions(sensor, (offsets - 0.5 * count) * pitch)
    origin = np.asarray(sensor.position, dtype=np.float64)
    rays = (*origin, *(np.ascontiguousarray(directions[:, i]) for i in range(3)))
    return _lines(through_surface(rays, surface, frame, n_w))


def _lines(passed) -> Rays:
    """`workers.setup.interface.Transmitted` as the kernels' lines (`Rays`), float64."""
    secant = passed.secant.astype(np.float64)
    return as_rays(
        x=passed.x,
        y=passed.y,
        z=passed.z,
        dx=passed.tan_x / secant,
        dy=passed.tan_y / secant,
        dz=-1.0 / secant,
        air=passed.air,
        weight=passed.transmittance,
    )


def _sea(surface, frame) -> Sea:
    """The kernels' `Sea`: the frame's centred elevation grid (size 0: flat)."""
    if surface is None:
        return Sea(np.zeros((1, 1)), 0.0, 0.0, 0.0, 0)
    axis = surface.axis
    elevation = np.asarray(surface.centred_elevation[frame], dtype=np.float64)
    x0, spacing = float(axis[0]), float(axis[1] - axis[0])
    return Sea(np.ascontiguousarray(elevation), x0, x0, spacing, int(axis.size))


def _sea_bounds(sea: Sea) -> tuple[float, float]:
    """Lowest and highest elevation of the sea's grid [m] (0, 0 over a flat sea)."""
    if sea.size == 0:
        return 0.0, 0.0
    return float(sea.elevation.min()), float(sea.elevation.max())


def _launch(sensor: Sensor, beam, surface, frame, n_w, rng, count, weight) -> Rays:
    """`count` photons of the Gaussian beam after the surface, as `transport`'s `Rays`.

    Tangent offsets (u, v) of the boresight are normal with variance tan²(φ/2)/2 each (the
    beam I0 = J e^(-r²/a²), a = R0 tan(φ/2)); every photon carries `weight` (raw power),
    times its Fresnel transmittance.
    """
    half = math.tan(0.5 * sensor.laser_fov)
    uv = rng.normal(scale=half / math.sqrt(2.0), size=(2, count))
    rotation = sensor.camera.rotation
    position = np.asarray(sensor.position, dtype=np.float64)
    tangents = np.stack([uv[0], uv[1], np.ones(count)], axis=-1)
    if beam == "parallel":
        directions = np.broadcast_to(rotation[2], tangents.shape)
        origins = position + sensor.reference_range * (tangents[:, :2] @ rotation[:2])
        rays = (*(np.ascontiguousarray(origins[:, i]) for i in range(3)),)
    else:
        directions = (tangents / np.linalg.norm(tangents, axis=-1, keepdims=True)) @ rotation
        rays = tuple(position)
    rays = (*rays, *(np.ascontiguousarray(directions[:, i]) for i in range(3)))
    lines = _lines(through_surface(rays, surface, frame, n_w))
    return lines._replace(weight=weight * lines.weight)


def _mask(centres, setup: Setup, shape: TargetShape, pixels: int) -> np.ndarray:
    """The target's mask (`workers.dataset.labels.target_mask`) from lines through each pixel.

    The share of a pixel covered is that of its `MASK_LINES`² lines of sight meeting the
    target (`workers.targets.base.TargetShape.meets`: float64 geometry, through the sea
    with its sub-grid slopes). A target that none meets but that the lines pass within
    one line spacing of its reach (`TargetShape.reach`) at its depth marks the pixel of
    the nearest line, so a target smaller than a pixel keeps its mask, as the fast
    renderer's does.
    """
    target, centre = setup.target, setup.target_centre
    x, y, z, dx, dy, dz = centres[:6]
    meets = shape.meets(target, centre, centres)
    lines = pixels * MASK_LINES
    share = meets.reshape(pixels, MASK_LINES, pixels, MASK_LINES).mean(axis=(1, 3))
    if not meets.any():
        t = (-target.depth - z) / dz  # where each line crosses the target's depth
        gap = np.hypot(x + t * dx - centre[0], y + t * dy - centre[1])
        nearest = int(np.argmin(gap))
        neighbour = nearest + 1 if nearest % lines < lines - 1 else nearest - 1
        spacing = np.hypot(
            x[nearest] + t[nearest] * dx[nearest] - x[neighbour] - t[neighbour] * dx[neighbour],
            y[nearest] + t[nearest] * dy[nearest] - y[neighbour] - t[neighbour] * dy[neighbour],
        )
        if t[nearest] > 0 and gap[nearest] <= shape.reach(target) + spacing:
            row, col = divmod(nearest, lines)
            share[row // MASK_LINES, col // MASK_LINES] = 1.0 / MASK_LINES**2
    return target_mask(share)
