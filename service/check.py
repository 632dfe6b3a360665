"""``oceanlidar check``: how true the fast renderer is to transport on a sweep's own scenes.

A few points of the sweep, chosen to span its swept parameters (`spanning_points`), are
rendered by both renderers on the same sea, realisation 0's (`check_points`), and compared
gate by gate (`workers.fidelity.compare`): the background, the target's contrast and its
shadow, held to issue #36's bars. Nothing is written but the optional plot: the sweep's
output store is never opened.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from service.errors import BadOptionError, BadSweepError
from service.inputs import shown
from service.sweep import Plan
from workers.fidelity import (
    SIGMAS,
    GateCheck,
    Light,
    compare,
    fast_light,
    gate_kinds,
    transport_light,
)
from workers.settings.transport import Transport

__all__ = ["PointCheck", "check_points", "report_lines", "spanning_points", "transport_settings"]


@dataclass(frozen=True)
class PointCheck:
    """One point of the sweep checked.

    Attributes
    ----------
    point : int
        The point's index in the sweep.
    values : dict
        Its swept values, by dotted path.
    gates : list of GateCheck
        The comparison, gate by gate (`workers.fidelity.compare`).
    reference, fast : Light
        The images compared (transport's, with its errors; the fast renderer's).
    photons : int
        Photons the transport launched.
    seconds : tuple of float
        Seconds the transport and the fast renderer took.
    """

    point: int
    values: dict
    gates: list[GateCheck]
    reference: Light
    fast: Light
    photons: int
    seconds: tuple[float, float]

    @property
    def holds(self) -> bool:
        """Whether every gate holds."""
        return all(gate.holds for gate in self.gates)


def spanning_points(plan: Plan, count: int) -> list[int]:
    """At most `count` points of `plan` spanning its swept parameters: its corners first.

    Each swept parameter's values are placed on [0, 1] (numbers by value, anything else by
    the order in which its values first appear); from point 0, the point farthest (in
    Euclidean distance) from those chosen is added until `count` are chosen or every
    other point repeats a chosen one. For a grid these are its corners, the most
    distant first; ties go to the lowest index. Deterministic.

    Parameters
    ----------
    plan : Plan
        The sweep.
    count : int
        Most points, at least 1.

    Returns
    -------
    list of int
        The points' indices, in the order chosen.
    """
    places = np.zeros((len(plan.points), len(plan.swept)))
    for column, path in enumerate(plan.swept):
        values = [point[path] for point in plan.points]
        if all(isinstance(v, int | float) and not isinstance(v, bool) for v in values):
            numbers = np.asarray(values, dtype=np.float64)
        else:
            order = {}
            for value in values:
                order.setdefault(repr(value), len(order))
            numbers = np.array([order[repr(value)] for value in values], dtype=np.float64)
        span = numbers.max() - numbers.min()
        places[:, column] = (numbers - numbers.min()) / span if span > 0 else 0.0
    chosen = [0]
    distance = np.linalg.norm(places - places[0], axis=1)
    while len(chosen) < count and distance.max() > 0:
        best = int(np.argmax(distance))
        chosen.append(best)
        distance = np.minimum(distance, np.linalg.norm(places - places[best], axis=1))
    return chosen


def transport_settings(plan: Plan, *, photons: int | None) -> None:
    """Refuse a sweep `check` cannot compare, or a photon count out of range.

    Raises
    ------
    BadSweepError
        A point already rendered by Monte Carlo (``transport.method``).
    BadOptionError
        ``--photons`` out of the Monte Carlo's range (``transport.photons``).
    """
    for point, scene in enumerate(plan.scenes):
        if scene.transport.method != "small_angle":
            raise BadSweepError(
                f"transport.method: point {point} renders by {scene.transport.method} "
                "already; check holds the fast renderer (small_angle) to it, so check a "
                "sweep of small_angle points"
            )
    if photons is not None:
        limits = Transport.model_fields["photons"].metadata
        low = next(m.ge for m in limits if hasattr(m, "ge"))
        high = next(m.le for m in limits if hasattr(m, "le"))
        if not low <= photons <= high:
            raise BadOptionError(f"--photons {photons}: photons per frame run {low} to {high}")


def check_points(plan: Plan, points, *, photons: int | None = None, progress=None):
    """Render `points` of `plan` by both renderers, realisation 0's sea, and compare them.

    Parameters
    ----------
    plan : Plan
        The sweep (small_angle points: `transport_settings`).
    points : sequence of int
        The points to check (`spanning_points`).
    photons : int, optional
        Photons per frame of the transport; default each point's ``transport.photons``.
    progress : callable, optional
        Called with each `PointCheck` as it is done.

    Returns
    -------
    list of PointCheck
    """
    checks = []
    for point in points:
        sample = plan.sample(point * plan.realisations)
        scene = sample.scene
        if photons is not None:
            scene = scene.model_copy(
                update={"transport": scene.transport.model_copy(update={"photons": photons})}
            )
        started = time.perf_counter()
        reference = transport_light(scene, seed=sample.seed)
        middle = time.perf_counter()
        fast = fast_light(scene, seed=sample.seed)
        seconds = (middle - started, time.perf_counter() - middle)
        kinds = gate_kinds(scene, sea_std=reference.sea_std)
        gates = compare(reference, fast, kinds=kinds)
        check = PointCheck(
            point, sample.values, gates, reference, fast, scene.transport.photons, seconds
        )
        checks.append(check)
        if progress is not None:
            progress(check)
    return checks


def report_lines(check: PointCheck) -> list[str]:
    """One point's table: per gate, its kind, background ratio and the target's contrast.

    A measure outside its bar is marked ``FAIL`` with the bar it misses; one the reference
    does not resolve, ``?``.
    """
    values = ", ".join(f"{path}={shown(value)}" for path, value in check.values.items())
    verdict = "holds" if check.holds else "FAILS"
    lines = [
        f"point {check.point}{f' ({values})' if values else ''}: {verdict} "
        f"({check.photons:,} photons: transport {check.seconds[0]:.1f} s, fast "
        f"{check.seconds[1]:.1f} s)",
        f"  gate kind    {'background (fast/transport)':<42} contrast: transport"
        "        fast  fast vs transport",
    ]
    for gate in check.gates:
        row = f"  {gate.gate:>4} {gate.kind:<7} {_shown(gate.background):<42}"
        if gate.contrast is not None:
            reference = f"{gate.reference_contrast:+.3f} ± {gate.reference_error:.3f}"
            row += f" {reference:>19} {gate.fast_contrast:+9.3f}  {_shown(gate.contrast)}"
        lines.append(row.rstrip())
    return lines


def _shown(measure) -> str:
    """A measure, its error and its verdict: ``1.02 ± 0.01``, ``FAIL (bar 5 %)``, ``?``."""
    if measure.ratio:
        text = f"{measure.value:.3f} ± {measure.error:.3f}"
        bar = f"{100 * measure.bar:g} %"
    else:
        text = f"{measure.value:+.3f} ± {measure.error:.3f}"
        bar = f"{measure.bar:g}"
    if not math.isfinite(measure.value):
        text = "n/a"
    if measure.holds is None:
        return f"{text} ?"
    if not measure.holds:
        return f"{text} FAIL (bar {bar} + {SIGMAS:g} se)"
    return text
