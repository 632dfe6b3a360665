"""How true the fast renderer is to photon transport, gate by gate: the comparison and its bars.

One scene's first frame is rendered by both renderers on the same sea (the same sample
seed): by photon transport (`workers.montecarlo.renderer.render_frame`, the reference, with its
standard error) and by the fast small-angle renderer (`workers.render.render_images`),
each with its target-free twin (`Scene.without_target`). `compare` then measures, per gate,

- the **background**: the fast twin's image mean over the reference twin's (a ratio);
- the **target's contrast** (target − twin)/twin over the reference's target mask: where
  the target lies in the gate (``inside``) or a gate's edge cuts it (``edge``), the fast
  contrast over the reference's (a ratio); where the gate lies below it (``shadow``) or
  above it (``above``), the fast contrast minus the reference's (a difference);

with the reference's standard error, and holds each to its bar (`BARS`, issue #36): the
background within 5 %, a contrast within 5 % inside a gate and 10 % at an edge, a shadow
(and the nothing above the target) within 0.05. A measure holds when its deviation is at
most its bar plus `SIGMAS` standard errors (the reference's noise must not fail a true
renderer: with 2, a measure at the bar fails one time in 40, a true one about never).
A contrast the reference does not resolve (below `RESOLVED` standard errors) is not held
to a ratio: it is reported, marked unresolved, and neither holds nor fails.

The gate's kind (`gate_kinds`) compares the gate's depths (`receiver.gates`, [top,
bottom] below the mean sea) with the target's extent [depth − radius, depth + radius] (a
disk: its depth), widened by the sea's reach: twice the standard deviation of the sample's
elevation (0 over a flat sea). A gate's edge within that reach of the target cuts it
somewhere under the waves (`edge`); a gate holding the widened extent is ``inside``; one
wholly below it ``shadow``, wholly above it ``above``.

`benchmarks.fidelity_reference` (the stored grid of reference scenes), its test and the
``oceanlidar check`` command (`service.check`) all measure through `compare`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from workers.montecarlo import renderer as montecarlo
from workers.render import render_images, render_pair
from workers.settings.scene import Scene
from workers.settings.seeds import SampleSeed
from workers.setup.builder import scene_setup

__all__ = [
    "BARS",
    "RESOLVED",
    "SEA_REACH",
    "SIGMAS",
    "GateCheck",
    "Light",
    "Measure",
    "compare",
    "fast_light",
    "first_frame",
    "gate_kinds",
    "transport_light",
]

BARS = {"background": 0.05, "inside": 0.05, "edge": 0.10, "shadow": 0.05, "above": 0.05}
"""The bars of issue #36: a background's ratio within 5 % of 1; a contrast's ratio within
5 % inside a gate, 10 % at an edge; a shadow's (or above the target, a null contrast's)
difference within 0.05."""

SIGMAS = 2.0
"""Standard errors of the reference a measure may lie beyond its bar and still hold."""

RESOLVED = 3.0
"""Standard errors a reference contrast must reach for its ratio to be held to a bar."""

SEA_REACH = 2.0
"""Standard deviations of the sea's elevation by which a gate's edge moves over the target."""


@dataclass(frozen=True)
class Light:
    """One renderer's first frame of a scene and of its target-free twin, on the same sea.

    Attributes
    ----------
    image, twin : ndarray, shape (gate, y, x)
        The noise-free images of the scene and of its twin [photoelectrons].
    stderr, twin_stderr : ndarray or None
        Their Monte Carlo standard errors (None: the fast renderer, deterministic).
    mask : ndarray, shape (y, x), bool, or None
        The target's mask (`workers.dataset.labels.target_mask`): the reference's only.
    sea_std : float or None
        Standard deviation of the sample's sea elevation [m] (0: flat): the reference's
        only.
    """

    image: np.ndarray
    twin: np.ndarray
    stderr: np.ndarray | None = None
    twin_stderr: np.ndarray | None = None
    mask: np.ndarray | None = None
    sea_std: float | None = None


@dataclass(frozen=True)
class Measure:
    """One measure of a gate held to its bar.

    Attributes
    ----------
    value : float
        The fast renderer's measure against the reference's: a ratio (background,
        contrast inside or at an edge) or a difference (shadow, above).
    error : float
        Its standard error from the reference's.
    bar : float
        The deviation allowed (`BARS`), before `SIGMAS` errors.
    ratio : bool
        Whether `value` is a ratio (its deviation ``value − 1``) or a difference.
    holds : bool or None
        Whether the deviation is within the bar plus `SIGMAS` errors; None when the
        reference does not resolve it.
    """

    value: float
    error: float
    bar: float
    ratio: bool
    holds: bool | None


@dataclass(frozen=True)
class GateCheck:
    """One gate compared: its kind, its background and the target's contrast.

    Attributes
    ----------
    gate : int
        The gate's number, from 1.
    kind : str
        ``inside``, ``edge``, ``shadow``, ``above`` (`gate_kinds`) or ``none`` (no target,
        or none in view: the background alone).
    background : Measure
        Fast twin's image mean over the reference twin's.
    contrast : Measure or None
        The target's contrast, fast against reference (None for ``none``).
    reference_contrast, reference_error, fast_contrast : float
        The contrasts (target − twin)/twin over the reference's mask, and the reference's
        standard error (nan for ``none``).
    """

    gate: int
    kind: str
    background: Measure
    contrast: Measure | None
    reference_contrast: float
    reference_error: float
    fast_contrast: float

    @property
    def holds(self) -> bool:
        """Whether no measure of the gate fails (an unresolved one does not fail)."""
        return all(m.holds is not False for m in (self.background, self.contrast) if m)


def first_frame(scene: Scene) -> Scene:
    """`scene` with one frame: the one both renderers compare."""
    return scene.model_copy(update={"sequence": scene.sequence.model_copy(update={"frames": 1})})


def transport_light(scene: Scene, *, seed: SampleSeed) -> Light:
    """The first frame by photon transport (`montecarlo.render_frame`), and its twin.

    The twin's photons are the same streams (`seed`) carried without the target, on the same
    sea, as `workers.render.render_arrays` renders it; here with its own standard error.

    Parameters
    ----------
    scene : Scene
        The scene; its ``transport`` gives the photons and batches (its method is ignored).
    seed : SampleSeed
        The sample's streams: its sea and its photons.

    Returns
    -------
    Light
    """
    scene = first_frame(scene).model_copy(
        update={"transport": scene.transport.model_copy(update={"method": "monte_carlo"})}
    )
    setup = scene_setup(scene)
    surface = setup.surface(seed, np.zeros(1))
    lit = montecarlo.render_frame(setup, surface, 0, seed)
    if scene.target.shape == "none":
        dark = lit
    else:
        dark = montecarlo.render_frame(scene_setup(scene.without_target()), surface, 0, seed)
    return Light(
        image=lit.expected,
        twin=dark.expected,
        stderr=lit.stderr,
        twin_stderr=dark.stderr,
        mask=lit.mask.astype(bool),
        sea_std=_sea_std(surface),
    )


def fast_light(scene: Scene, *, seed: SampleSeed) -> Light:
    """The first frame by the fast renderer (`workers.render.render_images`), and its twin.

    Parameters
    ----------
    scene : Scene
        The scene (its ``transport.method`` is set to ``small_angle``).
    seed : SampleSeed
        The sample's streams: its sea.

    Returns
    -------
    Light
        Without standard errors, mask or sea (the reference's are compared).
    """
    scene = first_frame(scene).model_copy(
        update={"transport": scene.transport.model_copy(update={"method": "small_angle"})}
    )
    if scene.target.shape == "none":
        image = twin = render_images(scene, seed=seed)[0][0]
    else:  # its twin gathered in the same pass, as the twin's own render gives it
        image, _, twin, _ = render_pair(scene, seed=seed, twin_seed=seed)
        image, twin = image[0], twin[0]
    return Light(image=image, twin=twin)


def _sea_std(surface) -> float:
    """Standard deviation of the first frame's elevation [m] (0 for a flat sea)."""
    if surface is None:
        return 0.0
    return float(np.std(np.asarray(surface.centred_elevation[0], dtype=np.float64)))


def gate_kinds(scene: Scene, *, sea_std: float) -> tuple[str, ...]:
    """Each gate's place against the target: ``inside``, ``edge``, ``shadow`` or ``above``.

    Parameters
    ----------
    scene : Scene
        The scene (its gates' depths and its target).
    sea_std : float
        Standard deviation of the sea's elevation [m]: a gate's edge within `SEA_REACH`
        of them from the target's extent cuts it somewhere under the waves.

    Returns
    -------
    tuple of str
        One kind per gate; all ``none`` without a target.
    """
    gates = scene.receiver.gate_depths
    target = scene.target
    if target.shape == "none":
        return ("none",) * len(gates)
    half = target.radius if target.shape == "sphere" else 0.0
    reach = SEA_REACH * sea_std
    top, bottom = target.depth - half - reach, target.depth + half + reach
    kinds = []
    for gate_top, gate_bottom in gates:
        if gate_bottom <= top:
            kinds.append("above")
        elif gate_top >= bottom:
            kinds.append("shadow")
        elif gate_top <= top and gate_bottom >= bottom:
            kinds.append("inside")
        else:
            kinds.append("edge")
    return tuple(kinds)


def compare(reference: Light, fast: Light, *, kinds) -> list[GateCheck]:
    """The fast renderer's light against the reference's, gate by gate, held to `BARS`.

    Parameters
    ----------
    reference : Light
        The photon transport's (with standard errors).
    fast : Light
        The fast renderer's, of the same scene and sea.
    kinds : sequence of str
        Each gate's kind (`gate_kinds`).

    Returns
    -------
    list of GateCheck
        One per gate. The contrasts are taken over the reference's mask; a gate of a
        scene whose mask is empty (the target out of view) is compared as ``none``.
    """
    size = reference.twin[0].size
    mean = reference.twin.mean(axis=(1, 2))
    error = np.sqrt((reference.twin_stderr.astype(np.float64) ** 2).sum(axis=(1, 2))) / size
    ratio = fast.twin.mean(axis=(1, 2)) / mean
    mask = reference.mask
    if mask.any():
        ref_contrast, ref_error = _contrast(reference, mask)
        fast_contrast, _ = _contrast(fast, mask)
    else:
        kinds = ("none",) * len(kinds)
    checks = []
    for g, kind in enumerate(kinds):
        background = _measure(
            float(ratio[g]), float(error[g] / mean[g] * ratio[g]), BARS["background"], True
        )
        if kind == "none":
            checks.append(GateCheck(g + 1, kind, background, None, *(math.nan,) * 3))
            continue
        value, err, other = float(ref_contrast[g]), float(ref_error[g]), float(fast_contrast[g])
        if kind in ("inside", "edge"):
            resolved = abs(value) >= RESOLVED * err
            share = other / value if value != 0.0 else math.nan
            contrast = _measure(
                share, abs(share) * err / abs(value) if value else math.inf, BARS[kind], True
            )
            if not resolved:
                contrast = Measure(contrast.value, contrast.error, contrast.bar, True, None)
        else:
            contrast = _measure(other - value, err, BARS[kind], False)
        checks.append(GateCheck(g + 1, kind, background, contrast, value, err, other))
    return checks


def _measure(value: float, error: float, bar: float, ratio: bool) -> Measure:
    """A measure held to `bar` plus `SIGMAS` errors."""
    deviation = abs(value - 1.0) if ratio else abs(value)
    holds = bool(deviation <= bar + SIGMAS * error) if math.isfinite(value) else False
    return Measure(value, error, bar, ratio, holds)


def _contrast(light: Light, mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per gate, (target − twin)/twin over `mask`, and a bound on its standard error.

    The bound adds the two images' errors (their photons are the same streams, so
    correlated: the true error is smaller); zero for the fast renderer.
    """
    t = light.image[:, mask].astype(np.float64).mean(axis=1)
    b = light.twin[:, mask].astype(np.float64).mean(axis=1)
    if light.stderr is None:
        return t / b - 1.0, np.zeros_like(t)
    count = mask.sum()
    dt = np.sqrt((light.stderr[:, mask].astype(np.float64) ** 2).sum(axis=1)) / count
    db = np.sqrt((light.twin_stderr[:, mask].astype(np.float64) ** 2).sum(axis=1)) / count
    return t / b - 1.0, (dt + db * t / b) / b
