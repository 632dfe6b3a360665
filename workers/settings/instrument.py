"""The instrument's sections of a scene: platform, laser, receiver, radiometry, noise, sequence.

Validated settings only; the physics they describe is in `workers.setup.geometry`,
`workers.setup.sensor`, `workers.setup.gates`, `workers.receiver.radiometry` and
`workers.receiver.noise`. Every field
declares its unit as data (`workers.settings.section.units`).
"""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import Field, model_validator

from workers.settings.section import Section, units

__all__ = [
    "MLDC_GATES",
    "Laser",
    "Noise",
    "Platform",
    "Radiometry",
    "Receiver",
    "Sequence",
]

FOOT = 0.3048
"""One international foot in metres (exact)."""

MLDC_GATES: tuple[tuple[float, float], ...] = tuple(
    (top * FOOT, bottom * FOOT)
    for top, bottom in ((12, 32), (16, 36), (20, 40), (25, 40), (35, 45), (40, 50))
)
"""The six ML(DC) receiver gates (top, bottom) in metres of depth.

Carmona, Cérou & Blasco (2000), table 1: 12–32, 16–36, 20–40, 25–40, 35–45 and 40–50 ft.
"""


class Platform(Section):
    """Where the sensor head is and where it points (laser and receiver share a boresight)."""

    altitude: float = Field(
        34.0, gt=1.0, le=5000.0, description="Height above mean sea.", json_schema_extra=units("m")
    )
    nadir_deg: float = Field(
        0.0,
        ge=0.0,
        le=60.0,
        description="Angle of the central ray from the vertical.",
        json_schema_extra=units("degree"),
    )
    azimuth_deg: float = Field(
        0.0,
        ge=-360.0,
        le=360.0,
        description="Compass azimuth of the central ray, clockwise from north (+y). "
        "The image's top edge lies towards it.",
        json_schema_extra=units("degree"),
    )


class Laser(Section):
    """The illuminating laser: a Gaussian beam I0 = J exp(-r²/a²), r = a at the field edge."""

    beam: Literal["divergent", "parallel"] = Field(
        "divergent",
        description="`divergent` from the platform, or `parallel` rays.",
        json_schema_extra=units("1"),
    )
    field_of_view_deg: float | None = Field(
        None,
        gt=0.0,
        le=60.0,
        description="Full opening of the laser field; null: the receiver's.",
        json_schema_extra=units("degree"),
    )
    rays: int | None = Field(
        None,
        ge=8,
        le=4096,
        description="Rays per side of the laser's square ray lattice; null: one per "
        "receiver pixel spacing, offset half a step from the pixels' lines of sight. More "
        "rays leave the gates' rough-sea means within 2 % and lower the pixel texture "
        "(docs/model.md §3).",
        json_schema_extra=units("1"),
    )


GateList = Annotated[
    tuple[
        tuple[
            Annotated[float, Field(ge=0.0, le=500.0)], Annotated[float, Field(ge=0.0, le=500.0)]
        ],
        ...,
    ],
    Field(min_length=1, max_length=32),
]


class Receiver(Section):
    """The gated pinhole cameras (one per gate, common boresight)."""

    pixels: int = Field(
        128,
        ge=8,
        le=2048,
        description="Pixels per side of each image.",
        json_schema_extra=units("1"),
    )
    field_of_view_deg: float = Field(
        6.7,
        gt=0.1,
        le=60.0,
        description="Full field of view α (paper: 6.7).",
        json_schema_extra=units("degree"),
    )
    gates: Literal["mldc"] | GateList = Field(
        "mldc",
        description="`mldc` (the six ML(DC) gates) or a list of [top, bottom] depths.",
        json_schema_extra=units("m"),
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


class Radiometry(Section):
    """How the renderer's signal becomes photoelectrons (see ``docs/radiometry.md``).

    ``absolute`` (the default) applies the lidar equation (`workers.receiver.radiometry`): the
    pulse
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
        json_schema_extra=units("1"),
    )
    white_plane_photons: float | None = Field(
        None,
        ge=0.0,
        le=1.0e9,
        description="Normalised mode only (required there, refused in absolute mode): mean "
        "photoelectrons a pixel gets from a ρ = 1 Lambertian plane just under a flat sea at "
        "nadir, no water path; 0: no noise, signal in units of that plane.",
        json_schema_extra=units("photoelectrons"),
    )
    pulse_energy: float = Field(
        0.1,
        gt=0.0,
        le=10.0,
        description="Absolute mode: energy of one laser pulse leaving the transmitter; "
        "default 0.1 J, a flash-lamp-pumped frequency-doubled Nd:YAG.",
        json_schema_extra=units("J"),
    )
    wavelength: float = Field(
        532.0e-9,
        ge=350.0e-9,
        le=1100.0e-9,
        description="Absolute mode: laser wavelength, for the photon energy hc/λ only (the "
        "water presets stay those near 514 nm); default 532 nm.",
        json_schema_extra=units("m"),
    )
    receiver_aperture: float = Field(
        0.1,
        gt=0.0,
        le=2.0,
        description="Absolute mode: entrance-pupil diameter of each gated receiver; default "
        "0.1 m, a 150 mm f/1.5 lens on an 18 mm intensifier for a 6.7° field.",
        json_schema_extra=units("m"),
    )
    optics_transmission: float = Field(
        0.5,
        gt=0.0,
        le=1.0,
        description="Absolute mode: fraction of the light entering the aperture that reaches "
        "the photocathode (window, lens, 532 nm band-pass filter); default 0.5.",
        json_schema_extra=units("1"),
    )
    quantum_efficiency: float = Field(
        0.15,
        gt=0.0,
        le=1.0,
        description="Absolute mode: photoelectrons per photon at the intensifier's "
        "photocathode at the laser wavelength; default 0.15, a multialkali (S-20/S-25) "
        "cathode at 532 nm.",
        json_schema_extra=units("1"),
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


class Noise(Section):
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

    gain: float = Field(
        1.0,
        ge=1.0,
        le=1.0e6,
        description="ICCD gain.",
        json_schema_extra=units("counts/photoelectron"),
    )
    excess_noise: float = Field(
        1.0,
        ge=1.0,
        le=10.0,
        description="Excess-noise factor F of the intensifier.",
        json_schema_extra=units("1"),
    )


class Sequence(Section):
    """A video: the same surface realisation evolving while the platform moves."""

    frames: int = Field(
        1, ge=1, le=10000, description="Number of frames.", json_schema_extra=units("1")
    )
    interval: float = Field(
        0.1, gt=0.0, le=3600.0, description="Time between frames.", json_schema_extra=units("s")
    )
    velocity: tuple[float, float, float] = Field(
        (0.0, 0.0, 0.0),
        description="Platform velocity (east, north, up).",
        json_schema_extra=units("m/s"),
    )
