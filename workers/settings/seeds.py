"""Random streams of a sample, keyed by position, never by draw order (docs/model.md §0)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["SampleSeed"]

_SURFACE, _NOISE, _PHOTONS = 0, 1, 2


@dataclass(frozen=True)
class SampleSeed:
    """The seeds of one sample.

    The surface stream depends on (`root`, `realisation`) only, so every parameter point
    of a sweep sees the same sea surfaces (common random numbers: a "with target" sample and
    its "without target" twin differ by the target alone). The noise stream depends on
    (`root`, `point`, `realisation`).

    Parameters
    ----------
    root : int
        The sweep's seed, >= 0.
    point : int
        Index of the parameter point, >= 0.
    realisation : int
        Index of the Monte Carlo realisation, >= 0.
    """

    root: int
    point: int = 0
    realisation: int = 0

    def __post_init__(self):
        for name in ("root", "point", "realisation"):
            value = getattr(self, name)
            if not isinstance(value, int | np.integer) or value < 0:
                raise ValueError(
                    f"SampleSeed.{name} must be a non-negative integer, got {value!r}"
                )

    def surface_rng(self, cascade: int = 0):
        """Generator for cascade `cascade` (finest first) of the surface realisation.

        Each cascade has its own stream, so a scene whose sea has one more (coarser)
        cascade draws the same waves in the cascades they share.
        """
        sequence = np.random.SeedSequence(
            self.root, spawn_key=(_SURFACE, self.realisation, int(cascade))
        )
        return np.random.Generator(np.random.PCG64(sequence))

    def noise_rng(self):
        """Generator for the sensor noise."""
        sequence = np.random.SeedSequence(
            self.root, spawn_key=(_NOISE, self.point, self.realisation)
        )
        return np.random.Generator(np.random.PCG64(sequence))

    def noise_seed(self) -> int:
        """The seed of a device generator for the sensor noise, in [0, 2⁶³).

        The first draw of `noise_rng` (``integers(2**63)``): what seeds the torch
        backend's generator (`workers.backends.backend.Backend.generator`) for this sample's noise,
        so that each sample of a batch draws from its own generator.
        """
        return int(self.noise_rng().integers(2**63))

    def photon_rng(self, frame: int = 0):
        """Generator for the Monte Carlo renderer's photon launches in `frame`.

        Like the surface, keyed by (`root`, `realisation`) and not by the point: a sample and
        its no-target twin follow the same photons, which differ only where they meet the
        target (common random numbers: `detect`'s pairs differ by the target alone).
        """
        sequence = np.random.SeedSequence(
            self.root, spawn_key=(_PHOTONS, self.realisation, int(frame))
        )
        return np.random.Generator(np.random.PCG64(sequence))

    def photon_key(self, frame: int = 0) -> int:
        """64-bit key of the photons' streams in `frame` (`scattering.photon_state`)."""
        sequence = np.random.SeedSequence(
            self.root, spawn_key=(_PHOTONS, self.realisation, int(frame), 1)
        )
        return int(sequence.generate_state(1, np.uint64)[0])
