"""Transport's gate gains: the water's return by photon transport, slab by slab in depth.

Wells' small-angle spread (`workers.fast.spread`) carries all forward-scattered light at
its depth and counts the backscattered share b_b as lost: a gate's water return is the
single-scattering integral π β(π) ∫ e^(−2Kz) dz over its slab, K = a + b_b. Held against
the Monte Carlo renderer in 1 m slabs (turbid harbour water, 32 px, 34 m, nadir,
``python -m benchmarks.turbid_time``), the fast renderer's return falls behind transport's
as the light's time grows: fast / transport 0.97, 0.94, 0.86, 0.89, 0.82, 0.89, 0.74,
0.74, 0.58 from 0–1 m to 8–9 m, the same with a laser of 20° over the 6.7° image
(so not light spread out of the image: its time, not its place), close to e^(−2 b_b z):
in water that scatters many times the light the small-angle theory counts as lost comes
back, late (docs/model.md §10).

Where that matters (`workers.setup.builder.time_resolved`: the backscatter's optical
depth to the deepest gate's bottom, b_b z, at least
`workers.setup.builder.BACKSCATTER_DEPTH`, or a phase function whose wide-angle tail
Wells' spread misses in any water, `paper`), `calibrated` multiplies each gate's
reflectance by the ratio of the two renderers' returns, tabulated per 1 m slab of depth by
the Monte Carlo renderer once per water (`slab_gains`, a fixed photon stream, so the same
bytes every time, in one view, `workers.setup.builder.TABULATION`, whatever the scene's:
`workers.setup.builder.slab_setups`), weighted over the gate's slab as its
single-scattering return is (`gate_time_gains`). A wing above both renderers, since it
runs both.
"""

from __future__ import annotations

import functools
from dataclasses import replace

import numpy as np

from workers.backends.backend import get_backend
from workers.fast import stages
from workers.fast.planes import frame_geometry
from workers.montecarlo.renderer import render_frame
from workers.optics.water import slab_backscatter_reflectance
from workers.settings.seeds import SampleSeed
from workers.setup.builder import SLAB
from workers.setup.compiled import Setup

__all__ = ["CALIBRATION_SEED", "calibrated", "gate_time_gains", "slab_gains"]

CALIBRATION_SEED = 20261128
"""Root seed of that run: the gains are a fixed quadrature, not the sample's randomness."""


@functools.lru_cache(maxsize=32)
def calibrated(setup: Setup, *, fast: Setup, transport: Setup) -> Setup:
    """`setup` with each gate's reflectance times its gain from the slabs of `fast`, `transport`.

    Parameters
    ----------
    setup : Setup
        A fast-renderer scene's setup, without gains (`workers.setup.builder.scene_setup`).
    fast, transport : Setup
        Its water's slab setups (`workers.setup.builder.slab_setups`).

    Returns
    -------
    Setup
        The same setup but its ``reflectances``, each times `gate_time_gains` of
        `slab_gains` (cached: one object per setup, as the setup's own caches want).
    """
    gains, _ = slab_gains(fast=fast, transport=transport)
    factors = gate_time_gains(
        gains=gains,
        gates=setup.gates,
        diffuse_attenuation=setup.water.diffuse_attenuation * setup.secant,
    )
    reflectances = tuple(r * g for r, g in zip(setup.reflectances, factors, strict=True))
    return replace(setup, reflectances=reflectances)


@functools.lru_cache(maxsize=16)
def slab_gains(*, fast: Setup, transport: Setup) -> tuple[np.ndarray, np.ndarray]:
    """Transport's water return over the fast renderer's, slab by slab (cached by the two).

    Parameters
    ----------
    fast, transport : Setup
        The same flat, target-free scene of `SLAB` gates from the surface down, one frame,
        compiled for the fast renderer (without gains) and for the Monte Carlo renderer
        (`workers.setup.builder.CALIBRATION_PHOTONS`): `workers.setup.builder.slab_setups`.

    Returns
    -------
    gains, errors : ndarray
        Per slab, the Monte Carlo renderer's mean image over the fast renderer's [1]
        (seed `CALIBRATION_SEED`) and its standard error [1]; 1 ± 0 where the fast
        renderer has no light.
    """
    light = stages.frame_light(fast, frame_geometry(fast, 0), None, 0, get_backend("numpy"))
    fast_means = light.images.astype(np.float64).mean(axis=(1, 2))
    transported = render_frame(transport, None, 0, SampleSeed(root=CALIBRATION_SEED))
    image = transported.expected.astype(np.float64)
    means = image.mean(axis=(1, 2))
    errors = np.sqrt((transported.stderr.astype(np.float64) ** 2).sum(axis=(1, 2)))
    errors /= image[0].size
    lit = fast_means > 0
    scale = np.where(lit, fast_means, 1.0)
    return np.where(lit, means / scale, 1.0), np.where(lit, errors / scale, 0.0)


def gate_time_gains(*, gains, gates, diffuse_attenuation) -> tuple[float, ...]:
    r"""Each gate's gain: its slabs' gains weighted by their single-scattering return.

    Parameters
    ----------
    gains : ndarray
        Gain of each `SLAB` from the surface down (`slab_gains`) [1].
    gates : sequence of tuple
        (top, bottom) depths of the gates along the central ray [m].
    diffuse_attenuation : float
        K sec ϑ_c along the central ray [1/m].

    Returns
    -------
    tuple of float
        :math:`\sum_s g_s w_s / \sum_s w_s`, :math:`w_s = \int e^{-2Kz}dz` over the part of
        slab s inside the gate [1].
    """
    edges = SLAB * np.arange(len(gains) + 1)
    out = []
    for top, bottom in gates:
        upper = np.clip(edges[:-1], top, bottom)
        lower = np.clip(edges[1:], top, bottom)
        weights = slab_backscatter_reflectance(
            backscatter_pi=1.0,
            diffuse_attenuation=diffuse_attenuation,
            top=upper,
            bottom=lower,
            reference=top,
        )
        out.append(float(np.sum(weights * gains) / np.sum(weights)))
    return tuple(out)
