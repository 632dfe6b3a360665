"""Target shapes as plug-ins: the interface both renderers use, and the registry by name.

A shape is one `TargetShape` subclass in its own module of `workers.targets`, registered
by name with `register` (the package imports every module, so the settings' choices and
both renderers see it). It gives:

- the fast renderer its maps on a plane grid (`TargetShape.impostor`: silhouette, lit
  reflectance, surface depth) and, where it can, the share of each cell's return a gate
  holds (`TargetShape.gated_share`); `SampledShape` derives both from the Monte Carlo
  record by tracing sub-lines through each cell, so a new shape needs no maps of its own;
- the Monte Carlo renderer its record (`TargetShape.record`, a named tuple of floats of
  its own type) and three compiled functions the kernels call, `target_distance`,
  `target_blocks` and `target_normal`: numba picks each shape's implementation from the
  record's type when it compiles a kernel (`compiled`), so the kernels hold no shape
  codes and stay cached on disk per shape.

Coordinates: x east, y north, z up [m] (a depth d is z = −d).
"""

from __future__ import annotations

from typing import NamedTuple

import numba
import numpy as np
from numba.extending import overload

from workers.targets.impostor import Impostor, offsets

__all__ = [
    "EPS",
    "SHAPES",
    "SampledShape",
    "TargetShape",
    "compiled",
    "register",
    "shape_named",
    "target_blocks",
    "target_distance",
    "target_normal",
]

EPS = 1e-7
"""Distance below which a surface met is the one just left [m]."""

SHAPES: dict[str, TargetShape] = {}
"""The registered shapes by name (`register`)."""


def register(shape: type[TargetShape]) -> type[TargetShape]:
    """Class decorator: register one instance of `shape` under its ``name``."""
    SHAPES[shape.name] = shape()
    return shape


def shape_named(name: str) -> TargetShape:
    """The registered shape called `name` (`KeyError` naming the choices if none)."""
    try:
        return SHAPES[name]
    except KeyError:
        choices = ", ".join(sorted(SHAPES))
        raise KeyError(f"unknown target shape {name!r}; choose from {choices}") from None


def target_distance(px, py, pz, dx, dy, dz, record):
    """Distance along the unit direction d to the target's surface facing the photon [m].

    inf if the line misses it, or starts inside it or within `EPS` of its surface. Compiled
    per shape (`compiled`); callable from numba code only.
    """


def target_blocks(x, y, z, ux, uy, uz, length, record):
    """Whether the target lies on the straight path from (x, y, z) along u for `length` [m].

    Compiled per shape (`compiled`); callable from numba code only.
    """


def target_normal(x, y, z, dx, dy, dz, record):
    """The outward unit normal (nx, ny, nz) at a point of the surface met along d.

    Compiled per shape (`compiled`); callable from numba code only.
    """


def compiled(record_class, *, distance, blocks, normal):
    """Register a shape's compiled functions for records of type `record_class`.

    Parameters
    ----------
    record_class : type
        The shape's named tuple of floats (`TargetShape.record`).
    distance, blocks, normal : numba dispatcher
        ``@njit`` functions with the signatures of `target_distance`, `target_blocks`
        and `target_normal`.
    """

    def mine(record):
        return getattr(record, "instance_class", None) is record_class

    @overload(target_distance)
    def _distance(px, py, pz, dx, dy, dz, record):
        if mine(record):
            return lambda px, py, pz, dx, dy, dz, record: distance(px, py, pz, dx, dy, dz, record)
        return None

    @overload(target_blocks)
    def _blocks(x, y, z, ux, uy, uz, length, record):
        if mine(record):
            return lambda x, y, z, ux, uy, uz, length, record: blocks(
                x, y, z, ux, uy, uz, length, record
            )
        return None

    @overload(target_normal)
    def _normal(x, y, z, dx, dy, dz, record):
        if mine(record):
            return lambda x, y, z, dx, dy, dz, record: normal(x, y, z, dx, dy, dz, record)
        return None


@numba.njit(cache=True)
def trace(origins, directions, record):
    """First hits of straight lines on the target: distances [m] and outward normals.

    Parameters
    ----------
    origins, directions : ndarray, shape (N, 3)
        Line starts [m] and unit directions.
    record : named tuple
        The shape's record (`TargetShape.record`).

    Returns
    -------
    distance : ndarray, shape (N,)
        Distance to the first hit [m], inf for a miss.
    normal : ndarray, shape (N, 3)
        Outward unit normal at the hit (0 for a miss).
    """
    count = origins.shape[0]
    distance = np.full(count, np.inf)
    normal = np.zeros((count, 3))
    for i in range(count):
        px, py, pz = origins[i, 0], origins[i, 1], origins[i, 2]
        dx, dy, dz = directions[i, 0], directions[i, 1], directions[i, 2]
        t = target_distance(px, py, pz, dx, dy, dz, record)
        if t < np.inf:
            distance[i] = t
            normal[i] = target_normal(px + t * dx, py + t * dy, pz + t * dz, dx, dy, dz, record)
    return distance, normal


class TargetShape:
    """A target shape: what each renderer needs of it (subclass, set ``name``, `register`).

    Methods take the scene's `workers.settings.target.Target` section (`target`) and the
    world (x, y) of its centre [m] (`centre`), placed by the setup.
    """

    name: str = ""
    fields: tuple[str, ...] = ()
    """The `Target` fields only this shape reads (beyond shape, radius, depth, x, y,
    reflectance): left out of the settings' dumps for other shapes while at their defaults."""

    shadings: tuple[str, ...] = ("lambert",)
    """The `Target.shading` values this shape renders (the paper's `ponder` is a sphere's)."""

    def check(self, target) -> None:
        """Raise ValueError naming the field if `target`'s values cannot be this shape."""

    def half_height(self, target) -> float:
        """Depth from the target's top to its centre plane [m] (0 for a flat target)."""
        return 0.0

    def reach(self, target) -> float:
        """Horizontal distance from the centre to the farthest point of the target [m]."""
        return float(target.radius)

    def record(self, target, centre) -> NamedTuple:
        """The Monte Carlo kernels' record of the target (its own named tuple type)."""
        raise NotImplementedError

    def impostor(self, *, grid, target, centre, refracted_nadir) -> Impostor:
        """The target's maps on `grid`, the plane through its centre (`Impostor`).

        `refracted_nadir` [rad] is the angle from the vertical of the lines through the
        cells in the water (flat sea), which run away from the platform.
        """
        raise NotImplementedError

    def gated_share(
        self, *, grid, target, centre, refracted_nadir, top, bottom, on, delays, shares
    ) -> np.ndarray | None:
        """Share of each cell's return a gate holds, or None.

        None: each cell then counts whole where its line's `Impostor.surface_depth` plus
        each delay lies in the gate.

        Arguments as `workers.targets.impostor.gated_share`, with the `target` section.
        """
        return None

    def meets(self, target, centre, lines) -> np.ndarray:
        """Which of the straight `lines` (x, y, z, dx, dy, dz; arrays [m], unit d) meet it."""
        origins = np.stack(lines[:3], axis=-1).astype(np.float64)
        directions = np.stack(lines[3:6], axis=-1).astype(np.float64)
        distance, _ = trace(origins, directions, self.record(target, centre))
        return np.isfinite(distance)


SUBLINES = (233, 144)
"""The Fibonacci lattice of lines `SampledShape` traces through each cell: N = 233 points
(i + ½)/N across, frac((i·144 + ½)/N) along, i < N: 233 distinct offsets on each axis, so a
target edge along either axis is resolved to 1/233 of a cell (a square S × S sub-grid would
resolve √N)."""


class SampledShape(TargetShape):
    r"""A shape whose fast-renderer maps are traced from its Monte Carlo record.

    Through each cell of the plane grid, N lines (`SUBLINES`, a Fibonacci lattice) along
    the flat-sea in-water direction
    :math:`\hat s = (\sin\vartheta\,\hat a, -\cos\vartheta)` (â away from the platform)
    meet the target (`trace`): the cell's occupancy is the share that hits, its surface
    depth their mean first-hit depth, and its weight
    :math:`\rho\,\overline{\cos i}/\cos\vartheta`, the cell's mean of the cosine of
    incidence (0 for a miss), as the sphere's Lambertian maps
    (`workers.targets.sphere`). The gate's share of a cell's return is the cos i-weighted
    share of its lines whose hit depth (plus each delay) the gate holds. Accurate to the
    lattice's spacing: a target narrower than a cell / √N may be missed.
    """

    def _lines(self, grid, target, centre, refracted_nadir, cells):
        """Trace the lattice's lines through `cells` (flat indices).

        Returns, per cell and line, whether it hits, its hit depth [m] and cos i [1] (0
        for a miss), and cos ϑ.
        """
        du, along = (values.ravel()[cells] for values in offsets(grid, centre))
        count, step = SUBLINES
        index = np.arange(count)
        su = (index + 0.5) / count - 0.5
        sv = np.mod((index * step + 0.5) / count, 1.0) - 0.5
        u = (du[:, None] + su * grid.spacing_u).ravel()
        a = (along[:, None] + sv * grid.spacing_v).ravel()
        away = -np.asarray(grid.axis_v[:2], dtype=np.float64)
        across = np.asarray(grid.axis_u[:2], dtype=np.float64)
        cos_t, sin_t = np.cos(refracted_nadir), np.sin(refracted_nadir)
        direction = np.array([sin_t * away[0], sin_t * away[1], -cos_t])
        back = 4.0 * (self.reach(target) + self.half_height(target) + 1.0)
        plane = np.stack(
            [
                centre[0] + u * across[0] + a * away[0],
                centre[1] + u * across[1] + a * away[1],
                np.full(u.shape, -grid.depth),
            ],
            axis=-1,
        )
        origins = plane - back * direction
        directions = np.broadcast_to(direction, origins.shape).copy()
        distance, normal = trace(origins, directions, self.record(target, centre))
        hit = np.isfinite(distance)
        depth = np.where(hit, -(origins[:, 2] + np.where(hit, distance, 0.0) * direction[2]), 0.0)
        cosine = np.where(hit, np.clip(-(normal @ direction), 0.0, 1.0), 0.0)
        shape = (cells.size, count)
        return hit.reshape(shape), depth.reshape(shape), cosine.reshape(shape), cos_t

    def _near(self, grid, target, centre, refracted_nadir):
        """Flat indices of the cells the target may cover (its bounding reach)."""
        du, along = offsets(grid, centre)
        spread = self.half_height(target) * 2.0 * np.tan(refracted_nadir)
        size = np.hypot(grid.spacing_u, grid.spacing_v)
        return np.flatnonzero(np.hypot(du, along) <= self.reach(target) + spread + size)

    def impostor(self, *, grid, target, centre, refracted_nadir) -> Impostor:
        """The traced maps on `grid` (see the class)."""
        cells = self._near(grid, target, centre, refracted_nadir)
        hit, depth, cosine, cos_t = self._lines(grid, target, centre, refracted_nadir, cells)
        occupancy, weight = np.zeros(grid.shape), np.zeros(grid.shape)
        surface = np.full(grid.shape, float(grid.depth))
        count = hit.sum(axis=1)
        occupancy.ravel()[cells] = count / hit.shape[1]
        weight.ravel()[cells] = target.reflectance * cosine.mean(axis=1) / cos_t
        hits = count > 0
        mean_depth = depth.sum(axis=1)[hits] / count[hits]
        surface.ravel()[cells[hits]] = mean_depth
        half = self.half_height(target)
        return Impostor(
            occupancy=occupancy.astype(np.float32),
            weight=weight.astype(np.float32),
            surface_depth=surface.astype(np.float32),
            top=grid.depth - half,
            bottom=grid.depth + half,
        )

    def gated_share(
        self, *, grid, target, centre, refracted_nadir, top, bottom, on, delays, shares
    ) -> np.ndarray:
        """The cos i-weighted share of each cell's traced lines a gate holds (see the class)."""
        cells = np.flatnonzero(on)
        _, depth, cosine, _ = self._lines(grid, target, centre, refracted_nadir, cells)
        top, bottom = (np.asarray(v, dtype=np.float64).ravel()[cells, None] for v in (top, bottom))
        whole = cosine.sum(axis=1)
        held = np.zeros(cells.size)
        for delay, share in zip(delays, shares, strict=True):
            inside = (depth + delay >= top) & (depth + delay <= bottom)
            held += share * (cosine * inside).sum(axis=1)
        out = np.zeros(grid.shape)
        out.ravel()[cells] = np.divide(held, whole, out=np.zeros(cells.size), where=whole > 0)
        return np.clip(out, 0.0, 1.0)
