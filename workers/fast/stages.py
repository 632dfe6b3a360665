"""The fast renderer's stages for one frame of one sample, on any array backend.

`frame_light` runs them in turn, each handing the next a named record: the rays through the
sea (`SeaRays`: the laser's rays down and the pixels' lines of sight, in the water), the
rays splatted on a plane (`Splat`), the light spread on a plane where the pixels read it
(`PlaneLight`), and the frame's light (`FrameLight`). The code is written once over the
array API (`workers.backends.backend.Backend.xp`), its loops in the backend's kernels
(`Backend.kernels`: numba for numpy, PyTorch's for torch); on numpy it is the numpy
renderer's code, byte for byte. The model is in `workers.render`'s docstring and
``docs/model.md``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from workers.backends.backend import Backend
from workers.backends.kernels import Cells
from workers.fast.planes import FrameGeometry, Plane
from workers.fast.targetgating import gate_shift
from workers.setup.compiled import Setup
from workers.setup.interface import Projected, through_surface, through_surface_and_resolved

__all__ = ["FrameLight", "PlaneLight", "SeaRays", "Splat", "frame_light"]


@dataclass(frozen=True)
class SeaRays:
    """One frame's rays after the sea surface, on the backend.

    Attributes
    ----------
    down : Projected
        The laser's rays in the water.
    up : Projected
        The pixels' lines of sight in the water.
    sight : Projected
        The pixels' lines of sight through the resolved sea alone (without the sub-grid
        slopes; `up` itself without them or without a target): what reads the target's
        light and the view it stops, which `workers.setup.compiled.Setup.subgrid_sway`
        blurs instead.
    power : array
        Each laser ray's power through the surface (beam share × Fresnel transmittance)
        [1], float32.
    up_transmittance, sight_transmittance : array
        Each line of sight's Fresnel transmittance, `up`'s and `sight`'s [1], float32.
    sight_height : array
        The sea's elevation where each of `sight`'s lines meets it [m], float32.
    down_excess, up_excess : array
        Each ray's air path less the central ray's [m], float32: its gates' timing.
    """

    down: Projected
    up: Projected
    sight: Projected
    power: object
    up_transmittance: object
    sight_transmittance: object
    sight_height: object
    down_excess: object
    up_excess: object


@dataclass(frozen=True)
class Splat:
    """Rays splatted on a two-level plane: the fine field, the far spread's coarse source.

    `rows` holds the fine rows and the coarse rows outside which `fine` and `source` are
    zero (power per area [1/m²], float32).
    """

    fine: object
    source: object
    rows: tuple[slice, slice]


@dataclass(frozen=True)
class PlaneLight:
    """A plane's light spread, on the fine cells the pixels read.

    `near` holds the fine rows ``window[0]:window[1]`` of the near spread, `far` the far
    spread on the coarse grid, `tail` the beam tail's near and far spreads (size 0: none),
    float32; `window` is `workers.backends.kernels.reach`'s.
    """

    near: object
    window: tuple[int, int, int, int]
    far: object
    tail: tuple

    @property
    def parts(self) -> tuple:
        """``(near, window, far, tail)``, for `workers.backends.kernels.gather_levels`."""
        return self.near, self.window, self.far, self.tail


@dataclass(frozen=True)
class FrameLight:
    """One frame's expected light, on the backend.

    Attributes
    ----------
    images : array, shape (gate, y, x)
        Expected photoelectrons (or the normalised signal), float32.
    silhouette : array or None, shape (y, x)
        With a target: each pixel's share of its line of sight inside the target's
        outline (`workers.dataset.labels.target_mask` makes the mask of it).
    free : array or None, shape (gate, y, x)
        With a target: the images of its target-free twin, the same spread light read
        without the target's light and shadow.
    """

    images: object
    silhouette: object
    free: object


def frame_light(
    setup: Setup, geometry: FrameGeometry, surface, frame: int, backend: Backend
) -> FrameLight:
    """One frame's light: rays through the sea, then each plane's light at the pixels.

    Parameters
    ----------
    setup : Setup
        The scene's setup.
    geometry : FrameGeometry
        The frame's geometry on `backend` (`FrameGeometry.on`).
    surface : Surface or None
        The sample's sea on `backend` (None: flat).
    frame : int
        The frame's index.
    backend : Backend
        Where the arrays live.

    Returns
    -------
    FrameLight
    """
    xp = backend.xp
    rays = _sea_rays(setup, geometry, surface, frame)
    pixels = setup.pixels
    shape = (len(setup.gates), pixels * pixels)
    images = xp.zeros(shape, dtype=xp.float32, device=backend.device)
    free = silhouette = None
    if geometry.impostor is not None:
        free = xp.zeros(shape, dtype=xp.float32, device=backend.device)
        silhouette = _target_frame(geometry, rays, images, backend)
    # float64 slab integrals where the surface cuts a gate's slab, on the rays' backend
    # (`workers.setup.gates.gate_gains`: on torch every ray on the device, nothing read back)
    down_gains = setup.gate_gains(rays.down_excess)
    up_gains = setup.gate_gains(rays.up_excess)
    hidden = _hidden(geometry, rays, backend)
    for g, plane in enumerate(geometry.gate_planes):
        ray_power = rays.power * down_gains[g]
        weight = rays.up_transmittance * up_gains[g]
        outputs = [(weight, free[g], None)] if free is not None else []
        if plane.unseen is not None:
            weight = weight * (1.0 - hidden[g])
        outputs.append((weight, images[g], plane.lit))
        splat = _splat(plane, rays.down, ray_power, backend)
        light = _spread(plane, rays.up, splat, backend, tail=plane.tail)
        _gather(plane, rays.up, light, outputs, backend)
    # the near and far parts of a spread each ring a little below zero where almost no
    # light lands; their sum is light, never negative
    scale = float(np.float32(setup.scale))
    images = xp.clip(images, min=0.0) * scale
    if free is not None:
        free = xp.reshape(xp.clip(free, min=0.0) * scale, (-1, pixels, pixels))
        silhouette = xp.reshape(silhouette, (pixels, pixels))
    return FrameLight(
        images=xp.reshape(images, (-1, pixels, pixels)), silhouette=silhouette, free=free
    )


def _hidden(geometry: FrameGeometry, rays: SeaRays, backend: Backend) -> dict:
    """Per gate with a shadow, the share of each pixel's view the target stops.

    Each gate's `Plane.unseen` read where the pixels' lines through the resolved sea cross
    the target's plane: every gate's map is on the same grid, so one pass reads them all.
    """
    gates = [g for g, plane in enumerate(geometry.gate_planes) if plane.unseen is not None]
    if not gates:
        return {}
    fields = tuple(geometry.gate_planes[g].unseen for g in gates)
    whole = (0, fields[0].shape[0], 0, fields[0].shape[1])
    values = _sample(rays.sight, geometry.sight_cells, fields, whole, backend)
    return {g: values[k] for k, g in enumerate(gates)}


def _sea_rays(setup: Setup, geometry: FrameGeometry, surface, frame: int) -> SeaRays:
    """The laser's rays and the pixels' lines of sight through the sea surface."""
    n_w = setup.water.refractive_index
    K = setup.water.diffuse_attenuation
    axes_grid = (geometry.target_plane or geometry.gate_planes[0]).grid
    central = float(np.float32(geometry.central_air))
    down = through_surface(geometry.lattice, surface, frame, n_w)
    # the pixels' lines of sight are never laser rays (`workers.setup.sensor.lattice_offset`)
    if getattr(surface, "subgrid", None) is not None and geometry.impostor is not None:
        # the target is read through the resolved sea
        up, sight = through_surface_and_resolved(geometry.pixel_rays, surface, frame, n_w)
        lines, sight_lines = up.on_axes(axes_grid, K), sight.on_axes(axes_grid, K)
    else:
        up = sight = through_surface(geometry.pixel_rays, surface, frame, n_w)
        lines = sight_lines = up.on_axes(axes_grid, K)
    return SeaRays(
        down=down.on_axes(axes_grid, K),
        up=lines,
        sight=sight_lines,
        power=geometry.laser_power * down.transmittance,
        up_transmittance=up.transmittance,
        sight_transmittance=sight.transmittance,
        sight_height=sight.z,
        down_excess=down.air - central,
        up_excess=up.air - central,
    )


def _target_frame(geometry: FrameGeometry, rays: SeaRays, images, backend: Backend):
    """Add the target's light to each gate's `images`; return the pixels' silhouette.

    The target's plane is lit by the spread light of the laser's rays at its depth,
    brought to the pixels' pitch (`workers.fast.planes.Resample`, where the laser's lattice
    is not at it), times each gate's reflectance map (`workers.fast.targetgating.TargetLight`),
    spread up again (with the sub-grid slopes' sway, `FrameGeometry.target_rise`) and
    gathered where the pixels' lines through the resolved sea cross the plane.
    """
    xp = backend.xp
    plane, rise = geometry.target_plane, geometry.target_rise
    levels, resample = plane.levels, geometry.resample
    occupancy = geometry.sight_occupancy
    silhouette = _sample(
        rays.sight, geometry.sight_cells, (occupancy,), geometry.sight_support, backend
    )[0]
    extra = rays.down.extra(levels.fine.depth)
    sight_extra = rays.sight.extra(levels.fine.depth)
    light = geometry.target_light
    if geometry.target_gating is not None:
        # the sea's height over the target moves the gates' depths across it (its mean
        # over the silhouette, 0 without one: one value read back to the host)
        held = xp.sum(silhouette)
        held = xp.where(held > 0.0, held, xp.ones_like(held))
        height = float(xp.sum(silhouette * rays.sight_height) / held)
        shift = gate_shift(geometry.target_gating.setup, height)
        if shift != 0.0:
            light = geometry.target_gating.light(shift).on(backend)
    rows = light.rows
    lit = rows if resample is None else resample.source_rows(rows)
    wide = any(coarse is not None for _, coarse in light.weights)
    splat = _splat(plane, rays.down, rays.power * extra, backend)
    reach = _reach(rise, rays.sight, backend)
    near, far, beyond = plane.spread.filtered(
        splat.fine,
        splat.source,
        rows_in=splat.rows,
        rows_out=(lit, levels.coarse_rows(lit)),
        far_out=wide,
    )
    if plane.tail is not None:
        near += plane.tail[0][lit]
        far += plane.tail[1]
        if wide:
            beyond += plane.tail[2]
    near += levels.upsample(far, rows=lit)
    fine = splat.fine
    if resample is not None:  # the light at the pixels' pitch
        across, along = resample.fine
        near = across[rows, lit] @ near @ along.T
        if wide:
            across, along = resample.coarse
            beyond = across @ beyond @ along.T
        fine = xp.zeros(rise.grid.shape, dtype=xp.float32, device=backend.device)
    inside = (rows, rise.levels.coarse_rows(rows))
    weight = rays.sight_transmittance * sight_extra
    for (weights, coarse), gates in zip(light.weights, light.gates, strict=True):
        fine[...] = 0.0
        fine[rows] = near * weights[rows]
        source = rise.levels.downsample(fine, rows)
        if coarse is not None:
            source += beyond * coarse
        seen = xp.zeros(images.shape[1], dtype=xp.float32, device=backend.device)
        rows_in = inside if coarse is None else (rows, slice(None))
        spread = _spread(rise, rays.sight, Splat(fine, source, rows_in), backend, reach=reach)
        _gather(rise, rays.sight, spread, ((weight, seen, None),), backend)
        for g in gates:
            images[g] += seen
    return silhouette


def _splat(plane: Plane, rays: Projected, power, backend: Backend) -> Splat:
    """Rays onto a plane: its fine field, the coarse source of its far spread, their rows."""
    xp = backend.xp
    levels = plane.levels
    fine = xp.zeros(levels.fine.shape, dtype=xp.float32, device=backend.device)
    source = xp.zeros(levels.coarse.shape, dtype=xp.float32, device=backend.device)
    grids = (levels.fine, levels.coarse)
    densities = tuple(np.float32(1.0 / (g.spacing_u * g.spacing_v)) for g in grids)
    block = tuple(b.start for b in levels.block)
    spans = backend.kernels.splat_levels(
        rays.lines, power, Cells.of(levels), densities, fine, source, block
    )
    return Splat(fine, source, (slice(*spans[:2]), slice(*spans[2:])))


def _spread(
    plane: Plane,
    sight: Projected,
    splat: Splat,
    backend: Backend,
    *,
    reach=None,
    tail=None,
):
    """A splat spread on its plane, on the rows the pixels' `sight` reaches.

    The light of the beam's `tail` (`Plane.tail`) is added to the spread. Only the rows
    that the sights read (their `reach`, `_reach`: found here when None) are brought back
    from the spectra.
    """
    window, coarse = _reach(plane, sight, backend) if reach is None else reach
    rows = slice(*window[:2])
    near, far, _ = plane.spread.filtered(
        splat.fine, splat.source, rows_in=splat.rows, rows_out=(rows, coarse)
    )
    none = _none(backend)
    return PlaneLight(near, window, far, (none, none) if tail is None else tail[:2])


def _reach(plane: Plane, sight: Projected, backend: Backend) -> tuple:
    """The fine cells the pixels' `sight` reads and the coarse rows the spread must hold.

    Returns `workers.backends.kernels.reach`'s window and a slice of coarse rows: those
    the window's upsampling reads and those where the lines that miss the fine grid cross
    the coarse one (what `gather_levels` reads for them), found in one pass.
    """
    levels = plane.levels
    *window, first, last = backend.kernels.reach(
        sight.lines, Cells.of(levels), plane.grid.shape, levels.coarse.shape
    )
    coarse = levels.coarse_rows(slice(*window[:2]))
    if first < last:
        if coarse.start < coarse.stop:
            first, last = min(first, coarse.start), max(last, coarse.stop)
        coarse = slice(first, last)
    return tuple(window), coarse


def _gather(plane: Plane, sight: Projected, light: PlaneLight, outputs, backend: Backend):
    """Add a plane's `light` at the pixels' sights to each of `outputs`, in one pass.

    `outputs` holds ``(weight, out, lit)`` triples: the light, times the share of each
    cell's light kept, `lit` (None: 1), and each pixel's `weight`, is added to `out`. Only
    the last output may keep a share (`workers.backends.kernels.gather_levels`): the
    others' `lit` is None.
    """
    lit = outputs[-1][2]
    levels = plane.levels
    backend.kernels.gather_levels(
        sight.lines,
        Cells.of(levels),
        plane.grid.shape,
        light.parts,
        levels.lift,
        _none(backend) if lit is None else lit,
        tuple(weight for weight, _, _ in outputs),
        tuple(out for _, out, _ in outputs),
    )


def _none(backend: Backend):
    """An empty float32 field on the backend: the kernels' "none"."""
    xp = backend.xp
    return xp.zeros((0, 0), dtype=xp.float32, device=backend.device)


def _sample(rays: Projected, cells: Cells, fields, box, backend: Backend):
    """`workers.backends.kernels.sample`: the fields at the rays, shape (len(fields), rays)."""
    xp = backend.xp
    out = xp.empty((len(fields), rays.base_u.shape[0]), dtype=xp.float32, device=backend.device)
    backend.kernels.sample(rays.lines, cells, tuple(fields), box, out)
    return out
