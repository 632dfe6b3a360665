"""The dataset's variables: one table of what a sample and a store hold.

Every variable a sample carries is one `Variable` entry of `variables`: its name,
dimensions, type, CF attributes, its `Role` (rendered by a task, or fixed by the scene
alone), whether a store keeps it in shards, and the rule its values must keep (`Rule`).
The renderer types and labels its arrays from it (`workers.dataset.labels.rendered_arrays`,
`labelled_dataset`), and the service builds the store's template, checks a sample's
values, computes statistics and reads samples from it. A new stored variable is one
entry here (and, if rendered, its values in `workers.dataset.labels.rendered_arrays`).
"""

from __future__ import annotations

import enum
import functools
from dataclasses import dataclass, field

import numpy as np

from workers.optics.fresnel import fresnel_reflectance
from workers.receiver.radiometry import lidar_equation
from workers.settings.scene import Scene
from workers.setup.builder import receiver_terms, scene_setup
from workers.setup.compiled import Setup

__all__ = [
    "COUNT_HEADROOM",
    "Role",
    "Rule",
    "Variable",
    "Visibility",
    "count_dtype",
    "rendered",
    "rendered_order",
    "variables",
    "white_plane_count",
]

COUNT_HEADROOM = 16.0
"""Largest expected count of a pixel over the brightest thing a scene shows (`count_dtype`):
room for the focusing of light by waves and for shading that returns more than a flat
plate (a white sphere under ``shading: paper``: twice), and for transport's gate gains
(`workers.calibration.timegains`, 0.9-1.8), which the planning does not tabulate. Not a
strict bound: a count beyond the store's type is caught when the sample is stored
(``valid_max``), never wrapped."""


class Visibility(enum.IntEnum):
    """The flags of ``target_visibility`` (`labels.visibility`): their stored values."""

    none = 0
    """The mask is empty: no target, or none of it in view."""
    in_gate = 1
    """The target brightens its mask by at least ``target.visibility_threshold``."""
    shadow = 2
    """The target darkens its mask by at least the threshold."""
    unseen = 3
    """The target changes its mask by less."""


class Role(enum.Enum):
    """Who writes a variable, and where it sits in a sample and in a store."""

    RENDERED = "rendered"
    """Per sample, rendered by a task (`workers.render.render_arrays`)."""
    LABEL = "label"
    """Per sample, fixed by the scene alone: written with the store's template."""
    TRACK = "track"
    """Per frame, fixed by the scene: a sample's coordinate, a store's per-sample variable."""
    COORDINATE = "coordinate"
    """Shared by every sample of a store (gates, frames, the surface grid)."""


class Rule(enum.Enum):
    """What a rendered variable's values must be for a sample to be stored.

    Every rule also holds a variable's ``valid_max``, where its attributes give one.
    """

    ANY = "any"
    """No further rule (the signal means are NaN without a target)."""
    FINITE = "finite"
    """No NaN nor infinity."""
    NON_NEGATIVE = "non-negative"
    """Finite and never below zero (counts, intensities and their errors)."""
    FLAG = "flag"
    """At most the largest of its ``flag_values``."""


@dataclass(frozen=True)
class Variable:
    """One variable of a sample: how it is named, shaped, typed, described and checked.

    Attributes
    ----------
    name : str
        The variable's name in a sample and in a store.
    dims : tuple of str
        Its dimensions in one sample (a store adds ``sample`` first, but to coordinates).
    dtype : numpy.dtype
        Its type.
    attrs : dict
        Its CF attributes (``long_name``, ``units``, flags, ``valid_max``).
    role : Role
        Who writes it.
    sharded : bool
        A store keeps it one sample per chunk inside shards (large per-sample arrays);
        otherwise one chunk per shard.
    rule : Rule
        What its values must be (`Rule`).
    """

    name: str
    dims: tuple[str, ...]
    dtype: np.dtype
    attrs: dict = field(hash=False)
    role: Role = Role.RENDERED
    sharded: bool = False
    rule: Rule = Rule.ANY


def white_plane_count(scene: Scene, setup: Setup) -> float:
    """Mean photoelectrons per pixel from a white plane just under a flat sea, at nadir.

    ``normalised`` radiometry: `white_plane_photons` by definition. ``absolute``: the lidar
    equation (`workers.receiver.radiometry.lidar_equation`, ρ = 1, d = 0) with the platform at its
    lowest during the sequence.

    Parameters
    ----------
    scene : Scene
        The sample's parameters (its radiometry).
    setup : Setup
        The scene's setup (`workers.setup.builder.scene_setup`): its platform's track, its
        laser's field [rad] and its water's refractive index.

    Returns
    -------
    float
        The mean count [photoelectrons].
    """
    r = scene.radiometry
    if r.mode == "normalised":
        return float(r.white_plane_photons)
    times = np.arange(scene.sequence.frames) * scene.sequence.interval
    lowest = min(float(setup.platform_position(t)[2]) for t in times)
    n_w = setup.water.refractive_index
    return float(
        lidar_equation(
            **receiver_terms(scene),
            beam_divergence=np.tan(0.5 * setup.laser_field_of_view),
            altitude=max(lowest, 1e-3),
            depth=0.0,
            reflectance=1.0,
            attenuation=0.0,
            refractive_index=n_w,
            transmittance=1.0 - float(fresnel_reflectance(1.0, n1=1.0, n2=n_w)),
        )
    )


def count_dtype(scene: Scene) -> np.dtype | None:
    """The unsigned integer type that holds every photoelectron count of `scene`'s images.

    The narrowest of uint8, uint16 and uint32 holding the largest possible count:
    `COUNT_HEADROOM` times the count of the brightest thing the scene shows, plus ten
    standard deviations of its Poisson noise. The brightest thing, in units of a white
    plane just under a flat sea (`white_plane_count`), is the brightest gate's water (its
    effective reflectance) or the target's top, its reflectance attenuated by e^(-2Kd).

    A Monte Carlo render (`workers.montecarlo.renderer`) holds uint32 counts: one rare large
    local estimate can make a pixel's expected count many times the brightest thing's.

    Returns
    -------
    numpy.dtype or None
        None when the images are not photoelectron counts (no photon budget, or an ICCD
        gain stage whose output is not whole photoelectrons): they stay float32.

    Raises
    ------
    ValueError
        Naming ``radiometry``, if the counts could exceed what uint32 holds.
    """
    noise = scene.noise
    if not scene.radiometry.photoelectrons or noise.gain != 1.0 or noise.excess_noise != 1.0:
        return None
    if scene.transport.method == "monte_carlo":
        return np.dtype(np.uint32)
    setup = scene_setup(scene)
    brightest = max(setup.reflectances)
    target = scene.target
    if target.shape != "none":
        top = max(target.depth - target.radius, 0.0)
        k = setup.water.diffuse_attenuation
        brightest = max(brightest, target.reflectance * np.exp(-2.0 * k * top))
    white = white_plane_count(scene, setup)
    mean = COUNT_HEADROOM * brightest * white
    largest = mean + 10.0 * np.sqrt(mean) + 10.0
    for dtype in (np.uint8, np.uint16, np.uint32):
        if largest <= np.iinfo(dtype).max:
            return np.dtype(dtype)
    raise ValueError(
        f"radiometry: a white plane under the sea would give {white:.3g} photoelectrons "
        f"per pixel, so counts could reach {largest:.3g}, more than the "
        f"{np.iinfo(np.uint32).max} an unsigned 32-bit count holds (lower pulse_energy "
        "or white_plane_photons)"
    )


def _flags(meanings: list[str]) -> dict:
    """CF flag attributes of flags 0, 1, ... (uint8) with these meanings."""
    return {
        "flag_values": np.arange(len(meanings), dtype=np.uint8),
        "flag_meanings": " ".join(meanings),
    }


def variables(scene: Scene) -> dict[str, Variable]:
    """The variables a sample of `scene` holds, in the order a store holds them.

    Parameters
    ----------
    scene : Scene
        The sample's parameters.

    Returns
    -------
    dict
        ``name -> Variable``: the rendered variables (``expected_stderr`` only when
        ``transport.method`` is ``monte_carlo``, ``surface_elevation`` only when the scene
        saves its surface), the labels, the platform track and the coordinates (``y``,
        ``x`` of the pixels, `workers.dataset.labels.image_axes`; ``sx``, ``sy`` with the
        surface). Units are CF's: photoelectron counts, ICCD output counts and signals
        in units of a white plane under the sea are all ``1``, and the ``long_name``
        says which. Photoelectron counts are unsigned integers
        (`count_dtype`, with ``valid_max``); everything else rendered is float32.
    """
    photoelectrons = scene.radiometry.photoelectrons
    counts = count_dtype(scene)
    if counts is not None:
        image = {"long_name": "photoelectron count with shot noise"}
        image["valid_max"] = counts.type(np.iinfo(counts).max)
    elif photoelectrons:
        image = {"long_name": "ICCD output count (photoelectrons times gain, with noise)"}
    else:
        image = {"long_name": "noise-free signal in units of a white plane under the sea"}
    signal = (
        "expected photoelectron count"
        if photoelectrons
        else "signal in units of a white plane under the sea"
    )
    f32, f64, u8, i32 = (np.dtype(t) for t in (np.float32, np.float64, np.uint8, np.int32))
    one = {"units": "1"}
    images, per_gate = ("frame", "gate", "y", "x"), ("frame", "gate")
    monte_carlo = scene.transport.method == "monte_carlo"
    where = "grid {} of the first frame's boresight sea point"
    table = [
        Variable(
            "image", images, counts or f32, {**image, **one}, sharded=True, rule=Rule.NON_NEGATIVE
        ),
        Variable(
            "expected",
            images,
            f32,
            {"long_name": f"{signal} (noise-free)", **one},
            sharded=True,
            rule=Rule.NON_NEGATIVE,
        ),
        Variable(
            "expected_stderr",
            images,
            f32,
            {"long_name": f"Monte Carlo standard error of the {signal} (noise-free)", **one},
            sharded=True,
            rule=Rule.NON_NEGATIVE,
        )
        if monte_carlo
        else None,
        Variable(
            "target_mask",
            ("frame", "y", "x"),
            u8,
            {
                "long_name": "pixel ray meets the target silhouette",
                **one,
                **_flags(["water", "target"]),
            },
            sharded=True,
            rule=Rule.FLAG,
        ),
        Variable(
            "surface_elevation",
            ("frame", "sy", "sx"),
            f32,
            {"long_name": "sea surface elevation (all cascades) at (sx, sy)", "units": "m"},
            sharded=True,
            rule=Rule.FINITE,
        )
        if scene.save_surface
        else None,
        Variable(
            "target_signal",
            per_gate,
            f32,
            {"long_name": f"mean {signal} inside the target mask (noise-free)", **one},
        ),
        Variable(
            "background_signal",
            per_gate,
            f32,
            {"long_name": f"mean {signal} in the ring around the target mask (noise-free)", **one},
        ),
        Variable(
            "target_effect",
            per_gate,
            f32,
            {
                "long_name": f"change of the mean {signal} inside the target mask made by the "
                "target (noise-free; the sample less its target-free twin)",
                **one,
            },
        ),
        Variable(
            "target_effect_relative",
            per_gate,
            f32,
            {
                "long_name": "target_effect over the target-free twin's mean inside the mask",
                **one,
                "comment": "NaN where the mask is empty; +-inf where the twin's mask is dark",
            },
        ),
        Variable(
            "target_visibility",
            per_gate,
            u8,
            {
                "long_name": "what the target shows in the gate",
                **one,
                **_flags([v.name for v in Visibility]),
                "comment": "from target_effect_relative: in_gate at or above "
                "+target.visibility_threshold (default 0.05), shadow at or below its "
                "negative, unseen between; none where the mask is empty",
            },
        ),
        Variable(
            "target_present",
            (),
            u8,
            {"long_name": "a target is in the scene", **one, **_flags(["absent", "present"])},
            Role.LABEL,
        ),
        Variable("time", ("frame",), f64, {"long_name": "time", "units": "s"}, Role.TRACK),
        Variable(
            "platform_x", ("frame",), f64, {"long_name": "platform east", "units": "m"}, Role.TRACK
        ),
        Variable(
            "platform_y",
            ("frame",),
            f64,
            {"long_name": "platform north", "units": "m"},
            Role.TRACK,
        ),
        Variable(
            "platform_z",
            ("frame",),
            f64,
            {"long_name": "platform height", "units": "m"},
            Role.TRACK,
        ),
        Variable(
            "gate",
            ("gate",),
            i32,
            {"long_name": "gate number (from 1, the shallowest; ML(DC): camera 1-6)", **one},
            Role.COORDINATE,
        ),
        Variable("frame", ("frame",), i32, {"long_name": "frame index", **one}, Role.COORDINATE),
        Variable(
            "gate_top",
            ("gate",),
            f64,
            {"long_name": "gate top depth", "units": "m"},
            Role.COORDINATE,
        ),
        Variable(
            "gate_bottom",
            ("gate",),
            f64,
            {"long_name": "gate bottom depth", "units": "m"},
            Role.COORDINATE,
        ),
    ]
    table += [
        Variable(
            axis,
            (axis,),
            f64,
            {"long_name": f"pixel centre {direction} on the sea", "units": "m"},
            Role.COORDINATE,
        )
        for axis, direction in (("y", "up the image"), ("x", "across the image"))
    ]
    if scene.save_surface:
        table += [
            Variable(
                axis,
                (axis,),
                f64,
                {"long_name": f"surface {where.format(direction)}", "units": "m"},
                Role.COORDINATE,
            )
            for axis, direction in (("sx", "east"), ("sy", "north"))
        ]
    return {variable.name: variable for variable in table if variable is not None}


def rendered(table: dict[str, Variable]) -> dict[str, Variable]:
    """The variables of `table` a task renders (`Role.RENDERED`), in the store's order."""
    return {name: v for name, v in table.items() if v.role is Role.RENDERED}


@functools.cache
def rendered_order() -> tuple[str, ...]:
    """The names of the rendered variables any scene may have, in the store's order.

    A store's arrays are written, and a sample's checksum taken, in this order: those of a
    scene rendered by Monte Carlo that saves its surface, which has every one.
    """
    every = Scene.model_validate({"transport": {"method": "monte_carlo"}, "save_surface": True})
    return tuple(rendered(variables(every)))
