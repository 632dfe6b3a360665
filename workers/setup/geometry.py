"""Sensor geometry: camera, laser, footprint and the in-water planes of the renderer.

The paper's pan/tilt pinhole camera, the laser's ray lattice, the footprint formula, and
the in-water planes on which light is spread and gathered.

World frame: x east, y north, z up, mean sea level z = 0. The platform (laser and receiver on
a common boresight) sits at ``(X0, Y0, H)``; the central ray meets mean sea level at the
world origin in the first frame.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
from scipy.fft import next_fast_len

__all__ = [
    "LaserRays",
    "Located",
    "PinholeCamera",
    "PlaneGrid",
    "fast_length",
    "flat_sea_point",
    "footprint_length",
    "gaussian_transfer",
    "pan_tilt_rotation",
]


def footprint_length(*, altitude, field_of_view, nadir):
    r"""Length of the sea-surface strip seen by a camera tilted by `nadir` (paper §4.2).

    Parameters
    ----------
    altitude : float or array_like
        Height h of the camera above mean sea level [m].
    field_of_view : float or array_like
        Full opening angle α of the field of view [rad].
    nadir : float or array_like
        Angle θ between the vertical and the central ray [rad].

    Returns
    -------
    float or ndarray
        The footprint length L1 [m].

    Notes
    -----
    The paper's formula,

    .. math:: L_1 = 2\left(-\frac{h}{\tan\alpha}
              + h\sqrt{1 + \frac{1}{\tan^2\alpha} + \tan^2\theta}\right),

    solves :math:`\alpha = \arctan\frac{L_1 - x}{h} + \arctan\frac{x}{h}` with
    :math:`\tan\theta = (L_1/2 - x)/h`, i.e. it assumes the central ray bisects the
    footprint. That holds at nadir (:math:`L_1 = 2h\tan(\alpha/2)`, exact) but not for a
    perspective camera at oblique angles, where it underestimates the exact
    :math:`h[\tan(\theta+\alpha/2) - \tan(\theta-\alpha/2)]` (by 2 % at 60°, α = 6.7°).
    The simulator only uses it to size the laser square; rays are traced exactly.

    References
    ----------
    Carmona, R., Cérou, F. & Blasco, B. (2000). Lidar imaging through the ocean surface,
    §4.2 "Field of View".
    """
    cot = 1.0 / np.tan(field_of_view)
    return 2.0 * altitude * (-cot + np.sqrt(1.0 + cot**2 + np.tan(nadir) ** 2))


def pan_tilt_rotation(*, pan, tilt):
    r"""The paper's rotation R taking world axes to camera axes (pan θ, then tilt α).

    Parameters
    ----------
    pan : float
        Pan angle θ between the camera x axis and the world X axis [rad].
    tilt : float
        Tilt angle α between the camera z axis and the world Z axis [rad].

    Returns
    -------
    ndarray, shape (3, 3)
        Rows are the camera x, y, z axes expressed in world coordinates.

    Notes
    -----
    .. math::
        R = \begin{bmatrix} \cos\theta & \sin\theta & 0 \\
            -\sin\theta\cos\alpha & \cos\theta\cos\alpha & \sin\alpha \\
            \sin\theta\sin\alpha & -\cos\theta\sin\alpha & \cos\alpha \end{bmatrix}

    References
    ----------
    Carmona, Cérou & Blasco (2000), §4.2 "The camera model"; Gonzalez, R. C. & Woods, R. E.,
    Digital Image Processing, §2.5 (camera model with gimbals).
    """
    ct, st, ca, sa = np.cos(pan), np.sin(pan), np.cos(tilt), np.sin(tilt)
    return np.array(
        [
            [ct, st, 0.0],
            [-st * ca, ct * ca, sa],
            [st * sa, -ct * sa, ca],
        ]
    )


@dataclass(frozen=True)
class PinholeCamera:
    """The paper's pinhole camera on pan/tilt gimbals, looking down at the sea.

    Parameters
    ----------
    position : tuple of float
        Lens centre (X0, Y0, Z0) in world coordinates [m].
    nadir : float
        Angle of the optical axis from the downward vertical [rad].
    azimuth : float
        Compass azimuth of the optical axis, clockwise from north (+y) [rad].
    field_of_view : float
        Full opening angle α across the image width [rad].
    pixels : int
        Pixels per side N.
    focal_length : float, optional
        λ [m]; it scales the image plane and cancels in every ray direction.

    Notes
    -----
    Looking down at compass azimuth φ with nadir angle ϑ is the paper's gimbal with pan
    θ = -φ and tilt α = π + ϑ: the camera z axis is then the line of sight, its x axis
    points to the right of the image (east when φ = 0) and its y axis down the image
    (towards the platform). Images are stored erect: row 0 is the far edge, column 0 the
    left edge. The paper's formula gives the inverted sensor image (x, y) = -(column, row)
    offsets; `project` returns it as written in the paper.
    """

    position: tuple[float, float, float]
    nadir: float
    azimuth: float
    field_of_view: float
    pixels: int
    focal_length: float = 0.05

    @property
    def rotation(self):
        """World-to-camera rotation R of the paper, shape (3, 3)."""
        return pan_tilt_rotation(pan=-self.azimuth, tilt=np.pi + self.nadir)

    @property
    def pixel_pitch(self):
        """Pixel size on the image plane [m]."""
        return 2.0 * self.focal_length * np.tan(0.5 * self.field_of_view) / self.pixels

    def project(self, points):
        r"""Image-plane coordinates of world points, :math:`\mathcal{C} = P R G \mathcal{W}`.

        Parameters
        ----------
        points : array_like, shape (..., 3)
            World points [m].

        Returns
        -------
        x, y : ndarray
            Image-plane coordinates [m] (the inverted sensor image of the paper).
        """
        lam = self.focal_length
        R = self.rotation
        image_centre = np.asarray(self.position) - lam * R[2]
        G = np.eye(4)
        G[:3, 3] = -image_centre
        P = np.eye(4)
        P[3, 2] = -1.0 / lam
        R4 = np.eye(4)
        R4[:3, :3] = R
        pts = np.asarray(points, dtype=float)
        homogeneous = np.concatenate([pts, np.ones((*pts.shape[:-1], 1))], axis=-1)
        c = homogeneous @ (P @ R4 @ G).T
        return lam * c[..., 0] / (lam * c[..., 3]), lam * c[..., 1] / (lam * c[..., 3])

    def pixel_of(self, x, y):
        """Fractional (row, column) of the erect image for image-plane coordinates (x, y)."""
        half = 0.5 * self.pixels - 0.5
        return -np.asarray(y) / self.pixel_pitch + half, -np.asarray(x) / self.pixel_pitch + half

    def pixel_directions(self, rows=slice(None), cols=slice(None)):
        """Unit world directions of the pixel-centre rays, shape (rows, cols, 3), float64.

        `rows` and `cols` pick image rows and columns (default all: shape (N, N, 3)).
        """
        offsets = (np.arange(self.pixels) + 0.5 - 0.5 * self.pixels) * (
            self.pixel_pitch / self.focal_length
        )
        u = offsets[np.newaxis, cols]
        v = offsets[rows, np.newaxis]
        camera = np.stack(np.broadcast_arrays(u, v, np.ones_like(u * v)), axis=-1)
        camera /= np.linalg.norm(camera, axis=-1, keepdims=True)
        return camera @ self.rotation


@dataclass(frozen=True)
class LaserRays:
    """A square lattice of laser rays with the paper's Gaussian profile.

    Attributes
    ----------
    origins : ndarray, shape (n, 3)
        Ray origins [m].
    directions : ndarray, shape (n, 3)
        Unit propagation directions.
    power : ndarray, shape (n,)
        Power carried by each ray, in units of J·m² (J = 1: the irradiance on the beam
        cross-section at the reference range).
    """

    origins: np.ndarray
    directions: np.ndarray
    power: np.ndarray
    rays: int

    @classmethod
    def central(
        cls, *, position, rotation, beam, field_of_view, rays, reference_range, offset=0.0
    ):
        """``(origins, directions)`` of the central ray and its right and lower neighbours.

        Of the lattice `from_platform` builds with the same arguments (without making it).
        """
        half = np.tan(0.5 * field_of_view)
        step = 2.0 * half / rays
        middle = (rays // 2 + 0.5 + offset - 0.5 * rays) * step
        u = np.array([middle, middle + step, middle])
        v = np.array([middle, middle, middle + step])
        probe = cls._from_offsets(
            u,
            v,
            position=position,
            rotation=rotation,
            beam=beam,
            half=half,
            step=step,
            reference_range=reference_range,
            rays=0,
        )
        return np.asarray(probe.origins, dtype=float), np.asarray(probe.directions, dtype=float)

    @classmethod
    def from_platform(
        cls,
        *,
        position,
        rotation,
        beam,
        field_of_view,
        rays,
        reference_range,
        margin=0,
        offset=0.0,
    ):
        r"""Build the lattice for a laser on the platform.

        Parameters
        ----------
        position : array_like, shape (3,)
            Laser position [m].
        rotation : ndarray, shape (3, 3)
            World-to-boresight rotation (the camera's); the beam axis is its third row.
        beam : {'divergent', 'parallel'}
            Rays fan out from `position`, or run parallel to the axis.
        field_of_view : float
            Full opening of the square the beam's 1/e radius spans [rad]; `rays` rays
            per side sample it.
        rays : int
            Rays per side across the field.
        reference_range : float
            Range along the axis at which the beam cross-section has irradiance
            :math:`J e^{-r^2/a^2}` with J = 1 [m].
        margin : int, optional
            Rays added on every side at the same pitch, beyond the field (default 0): the
            Gaussian beam goes on outside it.
        offset : float, optional
            Shift of the whole lattice along both of the boresight's tangent axes, in
            steps [1] (default 0: the rays at the centres of the field's `rays` × `rays`
            cells), so that the pixels' lines of sight need not be rays
            (`workers.setup.sensor.lattice_offset`).

        Notes
        -----
        :math:`I_0 = J e^{-r^2/a^2}` (paper §4.1), r the distance from the axis in a plane
        across the beam, a its value at the middle of the field's edge (the paper takes
        :math:`0 \le r/a \le 1` over the field). Rays sample the square on a lattice
        uniform in the tangent plane, so at the reference range each carries the power of
        an equal cross-section cell. A divergent beam's irradiance then falls as the inverse
        square of range, and refraction and the sea surface redistribute it. The beam holds
        :math:`\pi a^2 J` in all; the field's square holds erf(1)² = 71 % of it.
        """
        half = np.tan(0.5 * field_of_view)
        step = 2.0 * half / rays
        offsets = (np.arange(rays + 2 * margin) + 0.5 + offset - 0.5 * rays - margin) * step
        u, v = np.meshgrid(offsets, offsets)
        return cls._from_offsets(
            u.ravel(),
            v.ravel(),
            position=position,
            rotation=rotation,
            beam=beam,
            half=half,
            step=step,
            reference_range=reference_range,
            rays=rays + 2 * margin,
        )

    @classmethod
    def beam_tail(
        cls,
        *,
        position,
        rotation,
        beam,
        field_of_view,
        reference_range,
        inner,
        step,
        extent,
        centre=0.0,
    ):
        """The beam outside a square of the tangent plane, on a lattice of its own.

        Parameters
        ----------
        position, rotation, beam, field_of_view, reference_range
            As for `from_platform`.
        inner : float
            Half-width of the square left out, in tangent units [1]: a whole or
            half-whole number of steps, so that cell edges fall on it.
        step : float
            Lattice pitch in tangent units [1].
        extent : float
            Half-width of the lattice in units of the beam's 1/e radius [1].
        centre : float, optional
            Tangent offset of the left-out square's centre along both axes [1] (default
            0): the traced lattice's, when `from_platform` shifts it.

        Returns
        -------
        LaserRays
            Rays with |u| or |v| beyond `inner`, out to `extent` radii (`rays` is 0).
        """
        half = np.tan(0.5 * field_of_view)
        count = int(np.ceil(extent * half / step))
        # cell edges on ±inner, so the tail and the inner lattice tile the plane
        turn = (inner / step) % 1.0
        if min(turn, 1.0 - turn) < 1e-6:
            offsets = (np.arange(2 * count) + 0.5 - count) * step
        elif abs(turn - 0.5) < 1e-6:
            offsets = np.arange(-count, count + 1) * step
        else:
            raise ValueError("inner must be a whole or half-whole number of steps")
        u, v = np.meshgrid(offsets + centre, offsets + centre)
        keep = (np.maximum(np.abs(u - centre), np.abs(v - centre)) > inner).ravel()
        return cls._from_offsets(
            u.ravel()[keep],
            v.ravel()[keep],
            position=position,
            rotation=rotation,
            beam=beam,
            half=half,
            step=step,
            reference_range=reference_range,
            rays=0,
        )

    @classmethod
    def _from_offsets(cls, u, v, *, position, rotation, beam, half, step, reference_range, rays):
        """Rays through tangent offsets (u, v) of the boresight, each a step × step cell."""
        power = np.exp(-(u**2 + v**2) / half**2) * (reference_range * step) ** 2
        position = np.asarray(position, dtype=float)
        tangents = np.stack([u, v, np.ones_like(u)], axis=-1)
        if beam == "divergent":
            directions = (tangents / np.linalg.norm(tangents, axis=-1, keepdims=True)) @ rotation
            origins = np.broadcast_to(position, directions.shape)
        else:
            directions = np.broadcast_to(rotation[2], tangents.shape)
            origins = position + reference_range * (tangents[:, :2] @ rotation[:2])
        return cls(origins=origins, directions=directions, power=power, rays=rays)


def flat_sea_point(*, origin, direction, depth, refractive_index):
    """Where a ray from the air reaches `depth` after refraction by a flat sea.

    Parameters
    ----------
    origin : array_like, shape (..., 3)
        Ray origins above the sea [m].
    direction : array_like, shape (..., 3)
        Unit directions, pointing down.
    depth : float
        Depth of the horizontal plane [m].
    refractive_index : float
        Refractive index of the water [1].

    Returns
    -------
    ndarray, shape (..., 3)
        The point on the plane z = -depth [m].
    """
    origin = np.asarray(origin, dtype=float)
    direction = np.asarray(direction, dtype=float)
    at_surface = origin - origin[..., 2:3] / direction[..., 2:3] * direction
    horizontal = direction[..., :2]
    sin_air = np.linalg.norm(horizontal, axis=-1, keepdims=True)
    sin_water = sin_air / refractive_index
    tan_water = sin_water / np.sqrt(1.0 - sin_water**2)
    unit = np.divide(horizontal, sin_air, out=np.zeros_like(horizontal), where=sin_air > 0)
    xy = at_surface[..., :2] + depth * tan_water * unit
    return np.concatenate([xy, np.full((*xy.shape[:-1], 1), -depth)], axis=-1)


class Located(NamedTuple):
    """Points located on a `PlaneGrid`: the four cells around each and bilinear weights.

    Attributes
    ----------
    corners : ndarray, shape (4, ...), intp
        Flat indices of the cells (row, col), (row, col + 1), (row + 1, col) and
        (row + 1, col + 1), with (row, col) the cell whose centre is the nearest below
        and left of the point; 0 for points outside the grid. The trailing axes are
        the shape of the located points.
    weights : ndarray, shape (4, ...), float32
        Bilinear weights of those cells [1]: they sum to 1 for points inside the grid
        and are 0 for points outside.
    """

    corners: np.ndarray
    weights: np.ndarray


def fast_length(n):
    """Smallest even 5-smooth integer >= n (at least 2): a fast length for real FFTs.

    Twice `scipy.fft.next_fast_len`'s 5-smooth length for real transforms of half `n`
    (that of `n` itself may be odd: 13 gives 15); the same lengths as a search over the
    5-smooth numbers, checked for every `n` up to 200 000.
    """
    return 2 * next_fast_len(-(-max(int(n), 2) // 2), real=True)


@dataclass(frozen=True)
class PlaneGrid:
    """A horizontal plane at a depth, gridded along the image axes, where light is spread.

    The grid's u axis is the image's right (horizontal), its v axis the horizontal
    direction towards the platform (down the image). Cell (row, col) has its centre at
    ``origin + col·spacing_u·axis_u + row·spacing_v·axis_v``.

    Attributes
    ----------
    depth : float
        Depth of the plane [m].
    origin : tuple of float
        World (x, y) of the centre of cell (0, 0) [m].
    axis_u, axis_v : tuple of float
        Horizontal unit vectors of the columns and rows.
    spacing_u, spacing_v : float
        Cell sizes [m].
    shape : tuple of int
        (rows, columns), both even fast FFT lengths.
    """

    depth: float
    origin: tuple[float, float]
    axis_u: tuple[float, float]
    axis_v: tuple[float, float]
    spacing_u: float
    spacing_v: float
    shape: tuple[int, int]

    @classmethod
    def covering(cls, *, camera, lattice, depth, refractive_index, guard, multiple=1):
        """The grid that covers the camera's flat-sea footprint at `depth`.

        Parameters
        ----------
        camera : PinholeCamera
            The receiver; the grid covers where its pixels' rays reach `depth` under a
            flat sea, and its columns run along the image's right.
        lattice : tuple of ndarray
            ``(origins, directions)``, each (3, 3): three neighbouring laser rays, the
            central one, the next to its right and the next below. Cells are sized so
            that, under a flat sea, the laser lattice lands one ray per cell at the
            image centre: bilinear splatting then makes no moiré there (at oblique views
            the pitch drifts across the image, 0.87-1.18 cells at 45°, and a flat sea's
            images ring by a few per cent on some rows: docs/model.md §3).
        depth : float
            Depth of the plane [m].
        refractive_index : float
            Refractive index of the water [1].
        guard : int
            Guard band on every side [cells]: light spread near the image's edge stays
            on the grid.
        multiple : int, optional
            The grid's rows and columns are multiples of it (for `workers.fast.spread.Levels`).
        """
        rotation = camera.rotation
        axis_u = rotation[0, :2] / np.linalg.norm(rotation[0, :2])
        axis_v = np.array([axis_u[1], -axis_u[0]])
        rows = camera.pixel_directions(rows=[0, -1])
        cols = camera.pixel_directions(cols=[0, -1])
        edge = np.concatenate([rows[0], rows[1], cols[:, 0], cols[:, 1]])
        points = flat_sea_point(
            origin=np.asarray(camera.position, dtype=float),
            direction=edge,
            depth=depth,
            refractive_index=refractive_index,
        )[:, :2]
        centre, right, below = flat_sea_point(
            origin=lattice[0], direction=lattice[1], depth=depth, refractive_index=refractive_index
        )[:, :2]
        spacing_u = float(np.dot(right - centre, axis_u))
        spacing_v = float(np.dot(below - centre, axis_v))
        su = (points - centre) @ axis_u / spacing_u
        sv = (points - centre) @ axis_v / spacing_v
        cols = multiple * fast_length(np.ceil((su.max() - su.min() + 2 * guard) / multiple))
        rows = multiple * fast_length(np.ceil((sv.max() - sv.min() + 2 * guard) / multiple))
        first_u = 0.5 * (su.max() + su.min()) - 0.5 * (cols - 1)
        first_v = 0.5 * (sv.max() + sv.min()) - 0.5 * (rows - 1)
        corner = centre + first_u * spacing_u * axis_u + first_v * spacing_v * axis_v
        return cls(
            depth=float(depth),
            origin=(float(corner[0]), float(corner[1])),
            axis_u=(float(axis_u[0]), float(axis_u[1])),
            axis_v=(float(axis_v[0]), float(axis_v[1])),
            spacing_u=spacing_u,
            spacing_v=spacing_v,
            shape=(rows, cols),
        )

    def cell_coordinates(self, x, y):
        """Fractional (row, col) of world points (x, y) [m]; float32."""
        dx = np.asarray(x, dtype=np.float32) - np.float32(self.origin[0])
        dy = np.asarray(y, dtype=np.float32) - np.float32(self.origin[1])
        col = (dx * np.float32(self.axis_u[0]) + dy * np.float32(self.axis_u[1])) / np.float32(
            self.spacing_u
        )
        row = (dx * np.float32(self.axis_v[0]) + dy * np.float32(self.axis_v[1])) / np.float32(
            self.spacing_v
        )
        return row, col

    def cell_centres(self):
        """World (x, y) of every cell centre, each of shape `shape` [m]."""
        rows, cols = self.shape
        c = np.arange(cols) * self.spacing_u
        r = np.arange(rows) * self.spacing_v
        x = self.origin[0] + c[np.newaxis, :] * self.axis_u[0] + r[:, np.newaxis] * self.axis_v[0]
        y = self.origin[1] + c[np.newaxis, :] * self.axis_u[1] + r[:, np.newaxis] * self.axis_v[1]
        return x, y

    def locate(self, x, y):
        """Cells and bilinear weights of world points, for `splat` and `gather`.

        Parameters
        ----------
        x, y : ndarray
            World positions on the plane [m].

        Returns
        -------
        Located
            Reusable for every splat and gather at these points.
        """
        row, col = self.cell_coordinates(x, y)
        return self.locate_cells(row, col)

    def locate_cells(self, row, col):
        """`locate` for points given by fractional cell coordinates (float32 arrays).

        Parameters
        ----------
        row, col : ndarray
            Fractional (row, column) of the points, as from `cell_coordinates` [1].

        Returns
        -------
        Located
        """
        rows, cols = self.shape
        r0 = np.floor(row)
        c0 = np.floor(col)
        valid = (r0 >= 0) & (r0 < rows - 1) & (c0 >= 0) & (c0 < cols - 1)
        shape = valid.shape
        corners = np.empty((4, *shape), dtype=np.intp)
        base = r0 * cols
        base += c0
        corners[0] = np.where(valid, base, 0)
        np.add(corners[0], 1, out=corners[1])
        np.add(corners[0], cols, out=corners[2])
        np.add(corners[0], cols + 1, out=corners[3])
        fraction_row = np.subtract(row, r0, dtype=np.float32)
        right = np.subtract(col, c0, dtype=np.float32)
        right *= valid
        left = valid.astype(np.float32)
        left -= right
        weights = np.empty((4, *shape), dtype=np.float32)
        np.multiply(left, fraction_row, out=weights[2])
        np.subtract(left, weights[2], out=weights[0])
        np.multiply(right, fraction_row, out=weights[3])
        np.subtract(right, weights[3], out=weights[1])
        return Located(corners=corners, weights=weights)

    def splat(self, located, power):
        """Spread point powers bilinearly onto the cells: an irradiance map.

        Parameters
        ----------
        located : Located
            Where the rays cross the plane (`locate`).
        power : ndarray
            Power of each ray.

        Returns
        -------
        ndarray, shape `shape`, float32
            Power per unit horizontal area. Rays outside the grid are dropped.

        Notes
        -----
        One ``np.bincount`` over the four corners of every point: the float32 corner
        weights are accumulated in float64.
        """
        rows, cols = self.shape
        density = np.multiply(power, 1.0 / (self.spacing_u * self.spacing_v), dtype=np.float32)
        weight = located.weights * density
        total = np.bincount(located.corners.ravel(), weights=weight.ravel(), minlength=rows * cols)
        return total.astype(np.float32).reshape(rows, cols)

    def gather(self, field, located):
        """Bilinear interpolation of a cell field at located points (0 outside the grid).

        Returns
        -------
        ndarray
            The shape of the located points, in the dtype of `field`.
        """
        values = field.ravel().take(located.corners)
        values *= located.weights
        return values.sum(axis=0)

    def convolved(self, field, transfer, *, sway=None):
        """`field` on this grid convolved, linearly (zero-padded to twice its size).

        Parameters
        ----------
        field : ndarray
            Values on the cells, shape `shape`.
        transfer : callable
            The kernel's transfer function of the spatial-frequency magnitude [cycles/m]
            (an ndarray), real and even [1].
        sway : ndarray, optional
            The covariance, along (u, v), of a Gaussian also convolved [m²]
            (`gaussian_transfer`); None: none.

        Returns
        -------
        ndarray, shape `shape`, float64
        """
        rows, cols = self.shape
        shape = (2 * rows, 2 * cols)
        fv = np.fft.fftfreq(shape[0], d=self.spacing_v)[:, np.newaxis]
        fu = np.fft.rfftfreq(shape[1], d=self.spacing_u)[np.newaxis, :]
        spectrum = np.fft.rfft2(field, s=shape) * transfer(np.hypot(fv, fu))
        if sway is not None:
            spectrum *= gaussian_transfer(fu, fv, sway)
        return np.fft.irfft2(spectrum, s=shape)[:rows, :cols]

    def on_axes(self, covariance) -> np.ndarray:
        """A horizontal covariance in world (x, y) [m²] along this grid's (u, v) axes."""
        axes = np.array([self.axis_u, self.axis_v], dtype=np.float64)
        return axes @ np.asarray(covariance, dtype=np.float64) @ axes.T

    def frequency(self):
        """Spatial-frequency magnitude on the rfft2 grid of the cells [cycles/m]."""
        rows, cols = self.shape
        fv = np.fft.fftfreq(rows, d=self.spacing_v)
        fu = np.fft.rfftfreq(cols, d=self.spacing_u)
        return np.hypot(fv[:, np.newaxis], fu[np.newaxis, :])


def gaussian_transfer(fu, fv, covariance):
    r"""Transfer function of a 2-D Gaussian kernel [1].

    Parameters
    ----------
    fu, fv : ndarray
        Spatial frequencies along the u and v axes [cycles/m] (broadcast together).
    covariance : array_like, shape (2, 2)
        The kernel's covariance along (u, v) [m²].

    Returns
    -------
    ndarray
        :math:`\exp(-2\pi^2\,\mathbf f^\top C\,\mathbf f)`, float64.
    """
    (uu, uv), (_, vv) = np.asarray(covariance, dtype=np.float64)
    return np.exp(-2.0 * np.pi**2 * (uu * fu * fu + 2.0 * uv * fu * fv + vv * fv * fv))
