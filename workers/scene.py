"""The parameters of one sample: a frozen, validated description of the scene.

Every field carries its unit in its description, a default and a valid range. Angles that a
person types are in degrees and named ``*_deg``; everything else is SI (metres, seconds,
1/m). The nesting is what sweep files address with dotted paths (``target.depth``; see the
README's sweep file).
"""

from __future__ import annotations

import math
from typing import Annotated, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator

from workers import spectra
from workers.cascades import MAX_CASCADES, Sea, check_patches, default_patches
from workers.conditioning import Kriging, kriging
from workers.water import PRESETS

__all__ = [
    "MLDC_GATES",
    "Conditioning",
    "Laser",
    "Noise",
    "Platform",
    "Radiometry",
    "Receiver",
    "Scene",
    "Sequence",
    "SurfaceSpec",
    "Target",
    "Water",
    "footprint_span",
]

MAX_RAYS = 4096
"""Most laser rays per side (16.8 million rays)."""

MAX_PLANE_CELLS = 8192
"""Most cells per side of an in-water plane (a 0.5 GiB float64 splat)."""

FOOT = 0.3048
"""One international foot in metres (exact)."""

MLDC_GATES: tuple[tuple[float, float], ...] = tuple(
    (top * FOOT, bottom * FOOT)
    for top, bottom in ((12, 32), (16, 36), (20, 40), (25, 40), (35, 45), (40, 50))
)
"""The six ML(DC) receiver gates (top, bottom) in metres of depth.

Carmona, Cérou & Blasco (2000), table 1: 12–32, 16–36, 20–40, 25–40, 35–45 and 40–50 ft.
"""


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
    angle, unlike the paper's L1 of `workers.geometry.footprint_length`). A periodic sea
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


class _Model(BaseModel):
    model_config = ConfigDict(frozen=True, extra="forbid", validate_default=True)


PositiveFloat = Annotated[float, Field(gt=0.0, allow_inf_nan=False)]

Measurement = Annotated[
    list[Annotated[float, Field(allow_inf_nan=False)]], Field(min_length=3, max_length=4)
]


class Conditioning(_Model):
    """Measured elevations every surface of the scene honours (conditioning by kriging).

    A measurement is of the elevation the renderer sees at (x, y): the sum of the
    cascades' bilinear interpolations. Points lie on the coarsest cascade's patch [0, L)
    in x and y (`Scene.sea`; a point elsewhere is refused). Sweep files may give
    ``file: points.csv`` instead of ``points``; the service reads it (see
    `service.sweep`). See `workers.conditioning`.
    """

    points: list[Measurement] | None = Field(
        None,
        max_length=1000,
        description="Measured points [x, y, elevation] or [x, y, elevation, time], time "
        "on the frames' clock (default 0, the first frame); null: no conditioning "
        "[m, m, m, s].",
    )
    noise: float = Field(
        0.0, ge=0.0, le=10.0, description="Measurement noise standard deviation [m]."
    )


class SurfaceSpec(_Model):
    """Sea surface: the wave spectrum and the periodic grid it is synthesised on."""

    spectrum: Literal["elfouhaily", "phillips", "pierson_moskowitz", "jonswap", "flat"] = Field(
        "elfouhaily",
        description="Directional wave spectrum; `flat` is a mirror-flat sea.",
    )
    wind_speed: float = Field(
        5.0, ge=0.5, le=30.0, description="Wind speed 10 m above the sea, U10 [m/s]."
    )
    wind_direction_deg: float = Field(
        0.0,
        ge=-360.0,
        le=360.0,
        description="Direction the wind blows towards, counter-clockwise from +x (east) [deg].",
    )
    fetch: float = Field(1.0e5, gt=0.0, le=1.0e7, description="Fetch, used by `jonswap` only [m].")
    inverse_wave_age: float = Field(
        0.84,
        ge=0.84,
        le=5.0,
        description="Inverse wave age U10/c_p, used by `elfouhaily` only (0.84: fully "
        "developed sea) [1].",
    )
    grid_size: int = Field(
        256, ge=16, le=4096, description="Points per side of the periodic surface grid [1]."
    )
    spacing: float | None = Field(
        None,
        ge=1e-4,
        le=10.0,
        description="Grid spacing of the sea's finest cascade [m]; null: the receiver's "
        "footprint span over grid_size, so that the finest patch covers the footprint "
        "(docs/model.md §1).",
    )
    max_elevation: float | None = Field(
        None,
        gt=0.0,
        le=20.0,
        description="Optional rescaling (the paper's knob): max |elevation| over the frames "
        "[m]. Off by default; it breaks the spectrum's variance.",
    )
    conditioning: Conditioning = Conditioning()
    coarse_patches: list[PositiveFloat] | None = Field(
        None,
        max_length=MAX_CASCADES - 1,
        description="Periodic patches of the coarser cascades of the multi-scale sea, each "
        "sampled by grid_size points, increasing, each at most grid_size/16 times the one "
        "before, the first after the finest grid_size x spacing; null: chosen from the "
        "footprint and the spectrum (docs/model.md §1); []: the finest patch alone [m].",
    )
    allow_repeat: bool = Field(
        False,
        description="Render even if the receiver's footprint on the sea is wider than the "
        "coarsest cascade's periodic patch, so that the same waves repeat inside the "
        "image; refused otherwise.",
    )

    @model_validator(mode="after")
    def _even_grid(self) -> SurfaceSpec:
        if self.grid_size % 2:
            raise ValueError("grid_size must be even (FFT synthesis)")
        return self

    @model_validator(mode="after")
    def _cascades(self) -> SurfaceSpec:
        if self.coarse_patches and self.spacing is not None:
            try:
                check_patches(
                    grid_size=self.grid_size,
                    patches=[self.grid_size * self.spacing, *self.coarse_patches],
                )
            except ValueError as error:
                raise ValueError(
                    f"coarse_patches: {error} (patch 0 is grid_size x spacing)"
                ) from None
        return self

    @model_validator(mode="after")
    def _conditioning(self) -> SurfaceSpec:
        if not self.conditioning.points:
            return self
        if self.spectrum == "flat":
            raise ValueError("conditioning: a flat sea cannot honour measured elevations")
        if self.max_elevation is not None:
            raise ValueError(
                "conditioning: max_elevation would rescale the measured elevations away; "
                "leave it null"
            )
        return self

    def finest_spacing(self, span: float) -> float:
        """`spacing`, or by default the footprint's span over `grid_size` [m].

        Parameters
        ----------
        span : float
            Longest chord of the receiver's footprint along x or y [m] (`footprint_span`).
        """
        if self.spacing is not None:
            return self.spacing
        if not math.isfinite(span):
            raise ValueError(
                "surface.spacing: the footprint reaches the horizon, so the default spacing "
                "(footprint over grid_size) is undefined; give surface.spacing"
            )
        return span / self.grid_size

    def sea(self, span: float) -> Sea | None:
        """The cascades of the sea (None for a flat sea).

        Parameters
        ----------
        span : float
            Longest chord of the receiver's footprint along x or y [m]
            (`footprint_span`), for the default patches.

        Raises
        ------
        ValueError
            For a default spacing at a footprint that reaches the horizon, or
            `coarse_patches` that do not fit the finest patch.
        """
        spectrum = self.wave_spectrum()
        if spectrum is None:
            return None
        spacing = self.finest_spacing(span)
        if self.coarse_patches is None:
            patches = default_patches(
                spectrum, grid_size=self.grid_size, spacing=spacing, span=span
            )
        else:
            patches = (self.grid_size * spacing, *self.coarse_patches)
        try:
            return Sea(spectrum=spectrum, grid_size=self.grid_size, patches=tuple(patches))
        except ValueError as error:
            raise ValueError(
                f"surface.coarse_patches: {error} (patch 0 is grid_size x spacing)"
            ) from None

    def wave_spectrum(self) -> spectra.Spectrum | None:
        """The wave spectrum these settings describe (None for a flat sea)."""
        common = {
            "wind_speed": self.wind_speed,
            "wind_direction": np.radians(self.wind_direction_deg),
        }
        if self.spectrum == "flat":
            return None
        if self.spectrum == "elfouhaily":
            return spectra.Elfouhaily(**common, inverse_wave_age=self.inverse_wave_age)
        if self.spectrum == "phillips":
            return spectra.Phillips(**common)
        if self.spectrum == "pierson_moskowitz":
            return spectra.PiersonMoskowitz(**common)
        return spectra.Jonswap(**common, fetch=self.fetch)

    def kriging(self, sea: Sea | None) -> Kriging | None:
        """The kriging system of `conditioning` on `sea` (cached), or None without points.

        Raises
        ------
        ValueError
            For points off the coarsest patch, duplicates or a singular system
            (`workers.conditioning.kriging`).
        """
        if not self.conditioning.points:
            return None
        return kriging(
            sea,
            points=tuple(tuple(point) for point in self.conditioning.points),
            noise=self.conditioning.noise,
        )


class Water(_Model):
    """Inherent optical properties of the water column.

    A `preset` (Petzold 1972, via Mobley 1994, table 3.10) gives absorption, scattering and
    backscattering; any of the three given explicitly overrides it. With ``preset: null``
    all three are required.
    """

    preset: Literal["clear_ocean", "coastal", "turbid_harbour"] | None = Field(
        "coastal", description="Petzold water type, or null for explicit coefficients."
    )
    absorption: float | None = Field(
        None, ge=0.0, le=20.0, description="Absorption coefficient a [1/m]."
    )
    scattering: float | None = Field(
        None, ge=0.0, le=50.0, description="Scattering coefficient b [1/m]."
    )
    backscatter: float | None = Field(
        None, ge=0.0, le=5.0, description="Backscattering coefficient b_b [1/m]."
    )
    phase_function: Literal["paper", "wells"] = Field(
        "paper",
        description="Small-angle phase function: `paper` (s ∝ θ^-3/2 (θ0²+θ²)^-1/2) or "
        "`wells` (closed-form MTF exponent).",
    )
    theta0: float = Field(
        0.12, gt=0.0, le=1.0, description="Phase-function angular scale θ0 [rad] (paper: 0.12)."
    )
    refractive_index: float = Field(
        1.34, ge=1.0, le=2.0, description="Refractive index of sea water [1] (paper: 1.34)."
    )
    psf_truncation: float | None = Field(
        None,
        ge=0.5,
        lt=1.0,
        description="Share of the scattered light at which the point-spread function is "
        "cut off, light scattered further being dropped (the paper cuts at 0.95); null: "
        "the whole function [1].",
    )

    @model_validator(mode="after")
    def _complete(self) -> Water:
        if self.preset is None:
            missing = [
                name
                for name in ("absorption", "scattering", "backscatter")
                if getattr(self, name) is None
            ]
            if missing:
                raise ValueError(f"with preset null, set {', '.join(missing)} explicitly")
        coefficients = self.coefficients
        if coefficients["backscatter"] > coefficients["scattering"]:
            raise ValueError(
                f"backscatter {coefficients['backscatter']} 1/m exceeds scattering "
                f"{coefficients['scattering']} 1/m (backscattering is part of scattering)"
            )
        return self

    @property
    def coefficients(self) -> dict[str, float]:
        """Absorption, scattering and backscatter [1/m]: the preset with overrides."""
        values = dict(PRESETS[self.preset]) if self.preset is not None else {}
        for name in ("absorption", "scattering", "backscatter"):
            if getattr(self, name) is not None:
                values[name] = getattr(self, name)
        return values


class Target(_Model):
    """The object under the sea: a moored-mine sphere, a flat panel, or nothing."""

    shape: Literal["sphere", "disk", "none"] = Field(
        "sphere", description="`sphere`, `disk` (flat horizontal panel) or `none`."
    )
    radius: float = Field(0.3, gt=0.0, le=100.0, description="Sphere or disk radius [m].")
    depth: float = Field(
        5.0, gt=0.0, le=200.0, description="Depth of the sphere centre or of the disk [m]."
    )
    x: float | None = Field(
        None,
        ge=-1.0e4,
        le=1.0e4,
        description="East position [m]; null puts the target on the central ray "
        "(refracted by a flat sea).",
    )
    y: float | None = Field(
        None, ge=-1.0e4, le=1.0e4, description="North position [m]; null as for `x`."
    )
    reflectance: float = Field(
        0.2, ge=0.0, le=1.0, description="Lambertian reflectance ρ [1] (the paper's 20 % is 0.2)."
    )
    shading: Literal["lambert", "paper"] = Field(
        "lambert",
        description="Sphere shading: `lambert` (cosine of sphere normal and ray; physical), "
        "or `paper`, the paper's area weights (`ponder`), kept only to reproduce its "
        "figures: it does not conserve energy (a white sphere returns 2x a white disk of "
        "its radius where a Lambertian one returns 2/3, and its limb pixels exceed the "
        "brightest physical value several times over, more at finer pixels); do not use "
        "it for training data [1].",
    )

    @model_validator(mode="after")
    def _submerged(self) -> Target:
        if (self.x is None) != (self.y is None):
            raise ValueError(
                "set both x and y, or neither (the target then sits on the central ray)"
            )
        if self.shape == "sphere" and self.depth <= self.radius:
            raise ValueError(
                f"a sphere of radius {self.radius} m at depth {self.depth} m breaks the surface; "
                "depth must exceed radius"
            )
        return self


class Platform(_Model):
    """Where the sensor head is and where it points (laser and receiver share a boresight)."""

    altitude: float = Field(34.0, gt=1.0, le=5000.0, description="Height above mean sea [m].")
    nadir_deg: float = Field(
        0.0, ge=0.0, le=60.0, description="Angle of the central ray from the vertical [deg]."
    )
    azimuth_deg: float = Field(
        0.0,
        ge=-360.0,
        le=360.0,
        description="Compass azimuth of the central ray, clockwise from north (+y) [deg]. "
        "The image's top edge lies towards it.",
    )


class Laser(_Model):
    """The illuminating laser: a Gaussian beam I0 = J exp(-r²/a²), r = a at the field edge."""

    beam: Literal["divergent", "parallel"] = Field(
        "divergent", description="`divergent` from the platform, or `parallel` rays."
    )
    field_of_view_deg: float | None = Field(
        None,
        gt=0.0,
        le=60.0,
        description="Full opening of the laser field [deg]; null: the receiver's.",
    )
    rays: int | None = Field(
        None,
        ge=8,
        le=4096,
        description="Rays per side of the laser's square ray lattice [1]; null: one per "
        "receiver pixel spacing.",
    )


GateList = Annotated[
    list[
        tuple[Annotated[float, Field(ge=0.0, le=500.0)], Annotated[float, Field(ge=0.0, le=500.0)]]
    ],
    Field(min_length=1, max_length=32),
]


class Receiver(_Model):
    """The gated pinhole cameras (one per gate, common boresight)."""

    pixels: int = Field(128, ge=8, le=2048, description="Pixels per side of each image [1].")
    field_of_view_deg: float = Field(
        6.7, gt=0.1, le=60.0, description="Full field of view α [deg] (paper: 6.7)."
    )
    gates: Literal["mldc"] | GateList = Field(
        "mldc",
        description="`mldc` (the six ML(DC) gates) or a list of [top, bottom] depths [m].",
    )

    @model_validator(mode="after")
    def _ordered_gates(self) -> Receiver:
        if self.gates != "mldc":
            for index, (top, bottom) in enumerate(self.gates):
                if not top < bottom:
                    raise ValueError(f"gate {index}: top {top} m must be above bottom {bottom} m")
        return self

    @property
    def gate_depths(self) -> tuple[tuple[float, float], ...]:
        """Gate slabs as (top, bottom) depths in metres."""
        if self.gates == "mldc":
            return MLDC_GATES
        return tuple((float(top), float(bottom)) for top, bottom in self.gates)


class Radiometry(_Model):
    """How the renderer's signal becomes photoelectrons (see ``docs/radiometry.md``).

    ``absolute`` (the default) applies the lidar equation (`workers.radiometry`): the pulse
    energy spread over the Gaussian beam, the Fresnel transmittance both ways, attenuation,
    the 1/(nH + d)² spreading, the n² radiance loss into the air, the receiver's aperture,
    pixel solid angle and efficiencies. Counts then fall with altitude, depth and turbidity
    as in a real system. The defaults are of the order of an ML(DC)-class system (a
    frequency-doubled Nd:YAG laser and ICCD cameras); its exact figures are not public.

    ``normalised`` fixes the brightness per scene: a ρ = 1 Lambertian plane just under a
    flat sea at nadir reads `white_plane_photons`, whatever the altitude or the laser
    (the paper's N_s; ``configs/paper/``). ``white_plane_photons: 0`` means no noise,
    images in units of that plane.
    """

    mode: Literal["absolute", "normalised"] = Field(
        "absolute",
        description="`absolute` (the lidar equation with the system below) or `normalised` "
        "(brightness fixed per scene by `white_plane_photons`).",
    )
    white_plane_photons: float | None = Field(
        None,
        ge=0.0,
        le=1.0e9,
        description="Normalised mode only (required there, refused in absolute mode): mean "
        "photoelectrons a pixel gets from a ρ = 1 Lambertian plane just under a flat sea at "
        "nadir, no water path; 0: no noise, signal in units of that plane [photoelectrons].",
    )
    pulse_energy: float = Field(
        0.1,
        gt=0.0,
        le=10.0,
        description="Absolute mode: energy of one laser pulse leaving the transmitter; "
        "default 0.1 J, a flash-lamp-pumped frequency-doubled Nd:YAG [J].",
    )
    wavelength: float = Field(
        532.0e-9,
        ge=350.0e-9,
        le=1100.0e-9,
        description="Absolute mode: laser wavelength, for the photon energy hc/λ only (the "
        "water presets stay those near 514 nm); default 532 nm [m].",
    )
    receiver_aperture: float = Field(
        0.1,
        gt=0.0,
        le=2.0,
        description="Absolute mode: entrance-pupil diameter of each gated receiver; default "
        "0.1 m, a 150 mm f/1.5 lens on an 18 mm intensifier for a 6.7° field [m].",
    )
    optics_transmission: float = Field(
        0.5,
        gt=0.0,
        le=1.0,
        description="Absolute mode: fraction of the light entering the aperture that reaches "
        "the photocathode (window, lens, 532 nm band-pass filter); default 0.5 [1].",
    )
    quantum_efficiency: float = Field(
        0.15,
        gt=0.0,
        le=1.0,
        description="Absolute mode: photoelectrons per photon at the intensifier's "
        "photocathode at the laser wavelength; default 0.15, a multialkali (S-20/S-25) "
        "cathode at 532 nm [1].",
    )

    @model_validator(mode="after")
    def _photons_in_their_mode(self) -> Radiometry:
        if self.mode == "normalised" and self.white_plane_photons is None:
            raise ValueError(
                "mode normalised needs white_plane_photons (0: no noise, units of the plane)"
            )
        if self.mode == "absolute" and self.white_plane_photons is not None:
            raise ValueError(
                "white_plane_photons applies to mode normalised only; in mode absolute the "
                "counts follow from the lidar equation (set mode: normalised to fix them)"
            )
        return self

    @property
    def photoelectrons(self) -> bool:
        """Whether images are in photoelectrons (and noisy); False: units of the white plane."""
        return self.mode == "absolute" or bool(self.white_plane_photons)


class Noise(_Model):
    """Sensor noise: Poisson shot noise, optionally amplified by an ICCD.

    Shot noise is drawn whenever the images are in photoelectrons (`Radiometry`); the
    noisy ``image`` is then in counts, ``gain`` per photoelectron.
    """

    @model_validator(mode="before")
    @classmethod
    def _moved(cls, data):
        if isinstance(data, dict) and "photons" in data:
            raise ValueError(
                "noise.photons is now radiometry.white_plane_photons, with "
                "radiometry.mode: normalised (or use the default absolute mode)"
            )
        return data

    gain: float = Field(1.0, ge=1.0, le=1.0e6, description="ICCD gain [counts/photoelectron].")
    excess_noise: float = Field(
        1.0, ge=1.0, le=10.0, description="Excess-noise factor F of the intensifier [1]."
    )


class Sequence(_Model):
    """A video: the same surface realisation evolving while the platform moves."""

    frames: int = Field(1, ge=1, le=10000, description="Number of frames [1].")
    interval: float = Field(0.1, gt=0.0, le=3600.0, description="Time between frames [s].")
    velocity: tuple[float, float, float] = Field(
        (0.0, 0.0, 0.0), description="Platform velocity (east, north, up) [m/s]."
    )


class Scene(_Model):
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
    save_surface: bool = Field(
        False, description="Store the surface elevation of every frame with the sample."
    )

    @property
    def laser_rays(self) -> int:
        """Rays per side of the laser lattice: `laser.rays`, or the pixels' angular pitch."""
        if self.laser.rays is not None:
            return self.laser.rays
        return max(
            8, round(self.receiver.pixels * self._laser_half_width / self._receiver_half_width)
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

    def sea(self) -> Sea | None:
        """The cascades of the scene's sea (`SurfaceSpec.sea` at its footprint)."""
        return self.surface.sea(self.footprint())

    def surface_spacing(self) -> float:
        """Grid spacing of the sea's finest cascade (`SurfaceSpec.finest_spacing`) [m]."""
        return self.surface.finest_spacing(self.footprint())

    @model_validator(mode="after")
    def _footprint_within_sea_patch(self) -> Scene:
        surface = self.surface
        span = self.footprint()
        sea = surface.sea(span)
        if sea is None:
            if self.save_surface:
                self.surface_spacing()
            return self
        try:
            surface.kriging(sea)
        except ValueError as error:
            raise ValueError(f"surface.conditioning.points: {error}") from None
        period = sea.patches[-1]
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
                f"{surface.grid_size}, surface.spacing {sea.spacing(0):g} m, "
                f"surface.coarse_patches {surface.coarse_patches}): the same waves would "
                "repeat inside the image. Set surface.allow_repeat: true to render it anyway, "
                "or leave surface.coarse_patches null, narrow the field or lower the platform"
            )
        return self

    @model_validator(mode="after")
    def _altitude_during_sequence(self) -> Scene:
        climb = self.sequence.velocity[2] * self.sequence.interval * (self.sequence.frames - 1)
        if self.platform.altitude + climb <= 1.0:
            raise ValueError("the platform would reach the sea during the sequence")
        return self
