"""The photons' random streams and directions (numba): what one scattering draws.

Counter-keyed streams (a photon's state from its index and the frame's key: SplitMix64,
then xorshift64*), directions turned by a polar and an azimuthal angle, the tabulated phase
function (`workers.transport.PhaseTable`) evaluated and sampled, and the weight of a
direction drawn from the angular-biasing mixture (`workers.montecarlo.ANGULAR_BIAS`).
Used by `workers.photons`.
"""

from __future__ import annotations

import math

import numba
import numpy as np

__all__ = [
    "angle_between",
    "mixture_weight",
    "phase_value",
    "photon_state",
    "scattering_angle",
    "splitmix",
    "turn",
    "uniform",
]


@numba.njit(cache=True)
def splitmix(z):
    """SplitMix64's finaliser of z + the golden gamma (uint64)."""
    z = z + np.uint64(0x9E3779B97F4A7C15)
    z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    return z ^ (z >> np.uint64(31))


@numba.njit(cache=True)
def photon_state(key, index):
    """The non-zero xorshift state of photon `index` under `key` (uint64)."""
    state = splitmix(np.uint64(key) ^ splitmix(np.uint64(index)))
    if state == np.uint64(0):
        state = np.uint64(0x9E3779B97F4A7C15)
    return state


@numba.njit(cache=True)
def uniform(state):
    """Next uniform number in (0, 1) of a one-element xorshift64* state (advanced)."""
    x = state[0]
    x ^= x >> np.uint64(12)
    x ^= x << np.uint64(25)
    x ^= x >> np.uint64(27)
    state[0] = x
    r = x * np.uint64(0x2545F4914F6CDD1D)
    return (float(r >> np.uint64(11)) + 0.5) * (1.0 / 9007199254740992.0)


@numba.njit(cache=True)
def turn(ux, uy, uz, cos_t, sin_t, phi):
    """Direction at polar angle θ and azimuth φ about the unit vector u."""
    cp, sp = math.cos(phi), math.sin(phi)
    if abs(uz) > 0.99999:
        sign = 1.0 if uz > 0 else -1.0
        return sin_t * cp, sin_t * sp, sign * cos_t
    root = math.sqrt(1.0 - uz * uz)
    nx = sin_t * (ux * uz * cp - uy * sp) / root + ux * cos_t
    ny = sin_t * (uy * uz * cp + ux * sp) / root + uy * cos_t
    nz = -sin_t * cp * root + uz * cos_t
    norm = 1.0 / math.sqrt(nx * nx + ny * ny + nz * nz)
    return nx * norm, ny * norm, nz * norm


@numba.njit(cache=True)
def phase_value(cos_t, sin_t, log_theta0, log_step, log_values):
    """The tabulated phase function at the angle (cos θ, sin θ) [1/sr], log-linear."""
    theta = math.atan2(sin_t, cos_t)
    if theta <= 0.0:
        return math.exp(log_values[0])
    f = (math.log(theta) - log_theta0) / log_step
    if f <= 0.0:
        return math.exp(log_values[0])
    i = int(f)
    if i >= log_values.size - 1:
        return math.exp(log_values[-1])
    t = f - i
    return math.exp(log_values[i] * (1.0 - t) + log_values[i + 1] * t)


@numba.njit(cache=True)
def scattering_angle(u, quantiles):
    """Scattering angle [rad] at cumulative probability u, from the table's quantiles."""
    count = quantiles.size - 1
    f = u * count
    j = min(int(f), count - 1)
    return quantiles[j] + (f - j) * (quantiles[j + 1] - quantiles[j])


@numba.njit(cache=True)
def angle_between(ax, ay, az, bx, by, bz):
    """(cos, sin) of the angle between two unit vectors, the sine from their cross product."""
    cx, cy, cz = ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx
    return ax * bx + ay * by + az * bz, math.sqrt(cx * cx + cy * cy + cz * cz)


@numba.njit(cache=True)
def mixture_weight(dx, dy, dz, ax, ay, az, nx, ny, nz, phase, bias):
    """Weight factor of a direction n drawn from the biased mixture about d and a.

    The mixture (1 − ε) p(d·n) + ε p(a·n) (one-sample multiple importance sampling, the
    balance heuristic): the factor p(d·n) / mixture is at most 1/(1 − ε).
    """
    c1, s1 = angle_between(dx, dy, dz, nx, ny, nz)
    c2, s2 = angle_between(ax, ay, az, nx, ny, nz)
    own = phase_value(c1, s1, phase[0], phase[1], phase[2:])
    toward = phase_value(c2, s2, phase[0], phase[1], phase[2:])
    return own / ((1.0 - bias) * own + bias * toward)
