"""Measurement files: measured sea elevations read from CSV and inlined into a sweep's scene."""

from __future__ import annotations

import csv
import io
import math
import os
from pathlib import Path

from service.errors import BadFileError, BadSweepError
from service.inputs import read_text, shown

__all__ = ["inline_measurements", "read_measurements"]


def inline_measurements(data: dict, folder: Path | str) -> None:
    """Replace ``scene.surface.conditioning.file`` in `data` by the points it holds.

    The file is read from `folder` or below it, a local folder: a URL (the batch
    service's object-storage data root) reads no measurement file.
    """
    scene = data.get("scene")
    surface = scene.get("surface") if isinstance(scene, dict) else None
    conditioning = surface.get("conditioning") if isinstance(surface, dict) else None
    if not isinstance(conditioning, dict) or "file" not in conditioning:
        return
    place = "scene.surface.conditioning"
    name = conditioning.pop("file")
    if name is None:
        return
    if not isinstance(name, str) or not name or any(ord(c) < 32 for c in name):
        raise BadSweepError(f"{place}.file: must be the path of a CSV file, got {shown(name)}")
    if "://" in str(folder):
        raise BadSweepError(
            f"{place}.file: measurement files are read from a local folder only, not "
            f"{shown(str(folder))}; give the points inline ({place}.points)"
        )
    folder = Path(folder)
    relative = os.path.normpath(name)
    if os.path.isabs(relative) or relative.split(os.sep)[0] == os.pardir:
        raise BadSweepError(
            f"{place}.file: must name a file in the sweep file's folder or below it, "
            f"got {shown(name)}"
        )
    if not (folder / relative).resolve().is_relative_to(Path(folder).resolve()):
        raise BadSweepError(
            f"{place}.file: {shown(name)} leads out of the sweep file's folder (a symbolic "
            "link); copy the file there"
        )
    if conditioning.get("points") is not None:
        raise BadSweepError(f"{place}: give points or file, not both")
    conditioning["points"] = read_measurements(folder / relative, place=f"{place}.file")


def read_measurements(path, *, place: str = "measurements") -> list[list[float]]:
    """Measured elevations from a CSV file.

    The first line names the columns, ``x,y,elevation`` or ``x,y,elevation,time``
    (m, m, m, s); then one point a line. Blank lines and lines starting with ``#`` are
    skipped.

    Parameters
    ----------
    path : path-like
        The CSV file.
    place : str, optional
        Where the file was named, for error messages.

    Returns
    -------
    list of list of float
        One [x, y, elevation(, time)] per point, as ``surface.conditioning.points``
        takes them.

    Raises
    ------
    BadFileError
        If the file cannot be read, is larger than the sweep-file limit, or a line is
        not the header's number of finite numbers.
    """
    place = f"{place}: {shown(str(path))}"
    try:
        lines = [
            (number, row)
            for number, row in enumerate(
                csv.reader(io.StringIO(read_text(path, place=place), newline="")), start=1
            )
            if row and "".join(row).strip() and not row[0].lstrip().startswith("#")
        ]
    except csv.Error as error:
        raise BadFileError(f"{place}: not CSV ({error})") from None
    columns = ["x", "y", "elevation", "time"]
    header = [name.strip().lower() for name in lines[0][1]] if lines else []
    if header not in (columns[:3], columns):
        # the file's contents are never echoed: it may be any file the user can read
        raise BadFileError(
            f"{place}: must start with the header line x,y,elevation or x,y,elevation,time"
        )
    points = []
    for number, row in lines[1:]:
        try:
            values = [float(value) for value in row]
        except ValueError:
            values = []
        if len(values) != len(header) or not all(math.isfinite(v) for v in values):
            raise BadFileError(
                f"{place} line {number}: expected {len(header)} finite numbers "
                f"({','.join(header)})"
            )
        points.append(values)
    if not points:
        raise BadFileError(f"{place}: holds no points")
    return points
