"""The photons' random streams and directions (numba): what one scattering draws.

Counter-keyed streams (a photon's state from its index and the frame's key: SplitMix64,
then xorshift64*), directions turned by a polar and an azimuthal angle, the tabulated phase
function (`workers.optics.phases.base.PhaseTable`) evaluated and sampled, the way from a point in
the water to the receiver through a flat sea, and the weights of directions drawn from the
angular-biasing mixtures (`workers.montecarlo.renderer.ANGULAR_BIAS`,
`workers.montecarlo.renderer.TARGET_BIAS`).
Used by `workers.montecarlo.photons`.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from workers.montecarlo.records import LEAF

__all__ = [
    "angle_between",
    "mixture_weight",
    "phase_value",
    "photon_state",
    "reflection_weight",
    "scattering_angle",
    "splitmix",
    "toward_receiver",
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


@numba.njit(**LEAF)
def phase_value(cos_t, sin_t, phase):
    """The tabulated phase function at the angle (cos θ, sin θ) [1/sr], log-linear.

    `phase` is a `workers.montecarlo.records.Phase`.
    """
    log_values = phase.log_values
    theta = math.atan2(sin_t, cos_t)
    if theta <= 0.0:
        return math.exp(log_values[0])
    f = (math.log(theta) - phase.log_theta0) / phase.log_step
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


@numba.njit(**LEAF)
def mixture_weight(dx, dy, dz, ax, ay, az, nx, ny, nz, phase, bias):
    """Weight factor of a direction n drawn from the biased mixture about d and a.

    The mixture (1 − ε) p(d·n) + ε p(a·n) (one-sample multiple importance sampling, the
    balance heuristic): the factor p(d·n) / mixture is at most 1/(1 − ε).
    """
    c1, s1 = angle_between(dx, dy, dz, nx, ny, nz)
    c2, s2 = angle_between(ax, ay, az, nx, ny, nz)
    own = phase_value(c1, s1, phase)
    toward = phase_value(c2, s2, phase)
    return own / ((1.0 - bias) * own + bias * toward)


@numba.njit(**LEAF)
def reflection_weight(nx, ny, nz, ax, ay, az, ux, uy, uz, phase, bias):
    """Weight factor of a direction u reflected off a Lambertian surface of normal n.

    The direction is drawn from the mixture (1 − ε) cos(n·u)/π + ε p(a·u), the phase
    function about the way a to the receiver (one-sample multiple importance sampling,
    the balance heuristic): the factor (cos/π) / mixture, 0 into the surface, at most
    1/(1 − ε).
    """
    cos_n = nx * ux + ny * uy + nz * uz
    if cos_n <= 0.0:
        return 0.0
    own = cos_n / math.pi
    if bias == 0.0:
        return 1.0
    c, s = angle_between(ax, ay, az, ux, uy, uz)
    toward = phase_value(c, s, phase)
    return own / ((1.0 - bias) * own + bias * toward)


@numba.njit(**LEAF)
def toward_receiver(x, y, z, camera, n_w):
    """Unit direction from a point in the water to the receiver through a flat sea.

    The point (x, y, z) [m] below the mean sea level (a point above it is taken just
    below), the pinhole `camera` (a `workers.montecarlo.records.Point`) [m] above it: the
    crossing at horizontal distance r from the point toward the camera obeys Snell's law,
    n r / √(r² + d²) = (D − r) / √((D − r)² + H²), solved by Newton's method from the
    paraxial r = D d / (d + n H) (the receiver's image n H high), to 1e-12 of D.
    """
    ex, ey = camera.x - x, camera.y - y
    reach = math.sqrt(ex * ex + ey * ey)
    d = max(-z, 1e-9)
    height = camera.z
    if reach < 1e-12:
        return 0.0, 0.0, 1.0
    r = reach * d / (d + n_w * height)
    for _ in range(20):
        lw = math.sqrt(r * r + d * d)
        la = math.sqrt((reach - r) ** 2 + height * height)
        f = n_w * r / lw - (reach - r) / la
        slope = n_w * d * d / lw**3 + height * height / la**3
        step = f / slope
        r = min(max(r - step, 0.0), reach)
        if abs(step) < 1e-12 * reach:
            break
    norm = 1.0 / math.sqrt(r * r + d * d)
    return ex / reach * r * norm, ey / reach * r * norm, d * norm
