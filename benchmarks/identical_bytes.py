"""Every byte of a sweep's output, before and after a change that must not alter it (issue #38).

Runs one small sweep over the variants issue #38 moves (both renderers, every phase
function, sphere, disk and no target, flat and rough sea, an oblique view from a moving
platform, ``expected`` and the sea surface stored, 8 realisations so that ``detect``
accepts it) with ``oceanlidar run`` into a fresh temporary folder, then ``detect`` and
``info --verify`` on the store, through ``python -m service.cli`` (whatever the package's
layout). It writes a manifest, JSON, of every file there: the stores, the detection
dataset, the sweep file, and the text
``detect`` and ``info --verify`` printed. ``--against OLD.json`` compares it with an earlier
manifest, prints every file that differs, is missing or is new, and exits 1 if any does.

Two runs of the same code (53c95fc, two and one workers) wrote byte-identical stores and
detection datasets (443 of 443 files): no metadata key is volatile (no time, host or
duration is stored; the package's version is, and a bump shows as a difference, rightly).
The one volatile part is the temporary folder's path in the printed text, replaced by
``<WORK>`` before hashing; nothing else is normalised or skipped, and the manifest keeps
every file's raw md5 beside. The ``run`` command's own output (progress and run times) is
kept in the manifest, not compared. A planted change of 1e-6 relative in the fast
renderer's ``paper`` MTF exponent showed in 32 files (``expected`` and the checksums of the
3 shards holding those points, the signals, the statistics, 3 detection arrays; the noisy
counts did not move), the other 411 identical.
Usage (1 to 2.5 minutes on the loaded 2-core machine)::

    python benchmarks/identical_bytes.py --manifest-out after.json \\
        --against /work/notes/baseline/manifest.json [--code CHECKOUT] [--keep FOLDER]

``--code`` runs another checkout's ``service`` and ``workers`` (default: this script's);
``--keep`` copies the whole output, to diff a file that differs.
"""

import argparse
import hashlib
import json
import os
import shutil
import subprocess
import sys
import tempfile
from itertools import product
from pathlib import Path

import yaml

ROOT = Path(__file__).resolve().parent.parent

# The points: each renderer with each of its phase functions (the fast renderer reads
# `water.phase_function`, the Monte Carlo one `transport.phase_function`: the other field
# is set alike, or left at its default), over a flat and a rough sea, with a sphere, a disk
# and no target (the target-free points pair the others for `detect`).
RENDERERS = (
    ("small_angle", "fournier_forand", "fournier_forand"),
    ("small_angle", "paper", "paper"),
    ("small_angle", "wells", "fournier_forand"),
    ("monte_carlo", "fournier_forand", "fournier_forand"),
    ("monte_carlo", "paper", "paper"),
)
SEAS = ("flat", "elfouhaily")
SHAPES = ("sphere", "disk", "none")


def sweep() -> dict:
    """The sweep file, as a mapping: 30 points of 8 realisations at 32 x 32 pixels.

    Looking 10° off nadir from a platform moving at 2 m/s east, two frames 0.1 s apart (a
    scene set up per frame, and the stored image axes of an oblique view).

    The Monte Carlo points launch 40 000 photons a frame: at 4 000 one detector's scores
    were NaN at every realisation of a pair and ``detect`` stopped on a traceback (an
    ``IndexError`` in ``workers.detectors.detection.bootstrap_auc``, on 53c95fc).

    Returns
    -------
    dict
        The sweep, ``output`` relative to the folder it is written in.
    """
    points = [(*renderer, sea, shape) for renderer, sea, shape in product(RENDERERS, SEAS, SHAPES)]
    method, water, transport, sea, shape = (list(c) for c in zip(*points, strict=True))
    return {
        "name": "identical-bytes",
        "seed": 38,
        "realisations": 8,
        "output": "store.zarr",
        "scene": {
            "surface": {"spectrum": "elfouhaily", "wind_speed": 8.0, "grid_size": 32},
            "water": {"preset": "coastal"},
            "target": {"shape": "sphere", "radius": 0.3, "depth": 4.0, "reflectance": 0.2},
            "platform": {"altitude": 34.0, "nadir_deg": 10.0},
            "receiver": {"pixels": 32, "field_of_view_deg": 6.7, "gates": "mldc"},
            "radiometry": {"mode": "normalised", "white_plane_photons": 200.0},
            "sequence": {"frames": 2, "interval": 0.1, "velocity": [2.0, 0.0, 0.0]},
            "transport": {"photons": 40000, "batches": 4},
            "save_surface": True,
        },
        "store": {"expected": True},
        "sweep": {
            "method": "zip",
            "parameters": {
                "transport.method": {"values": method},
                "water.phase_function": {"values": water},
                "transport.phase_function": {"values": transport},
                "surface.spectrum": {"values": sea},
                "target.shape": {"values": shape},
            },
        },
    }


def oceanlidar(arguments: list[str], *, code: Path, cwd: Path, log: Path) -> str:
    """Run ``python -m service.cli`` with `arguments` in `cwd`; its stdout, also written to `log`.

    Parameters
    ----------
    arguments : list of str
        The command line after ``oceanlidar``.
    code : Path, keyword-only
        The checkout whose ``service`` and ``workers`` run (its folder is the PYTHONPATH).
    cwd : Path, keyword-only
        The folder it runs in.
    log : Path, keyword-only
        Where its stdout and stderr go.

    Returns
    -------
    str
        Its stdout. A non-zero exit stops the harness (exit 2), its output printed.
    """
    done = subprocess.run(
        [sys.executable, "-m", "service.cli", *arguments],
        cwd=cwd,
        capture_output=True,
        text=True,
        env={**os.environ, "PYTHONPATH": str(code)},
        check=False,
    )
    log.write_text(done.stdout + done.stderr)
    if done.returncode != 0:
        sys.exit(f"oceanlidar {' '.join(arguments)}: exit {done.returncode}\n{done.stderr}")
    return done.stdout


def manifest(work: Path) -> dict:
    """The md5 of every file under `work`, the folder's path replaced in the printed text.

    Parameters
    ----------
    work : Path
        The harness's folder: the stores, the detection dataset and the printed text.

    Returns
    -------
    dict
        ``files`` {relative path: md5 compared}, ``raw_md5`` {relative path: md5 of the
        bytes as written}.
    """
    files, raw = {}, {}
    for file in sorted(p for p in work.rglob("*") if p.is_file()):
        name = file.relative_to(work).as_posix()
        data = file.read_bytes()
        raw[name] = hashlib.md5(data).hexdigest()
        if file.suffix == ".txt":
            data = data.replace(str(work).encode(), b"<WORK>")
        files[name] = hashlib.md5(data).hexdigest()
    return {"files": files, "raw_md5": raw}


def compare(new: dict, old: dict) -> int:
    """Print every file that differs, is missing or is new; the count of them.

    Parameters
    ----------
    new, old : dict
        {relative path: md5}, the ``files`` of two manifests (`manifest`): this run's and
        the reference's.

    Returns
    -------
    int
        Files that differ, are missing from `new` or are new in it.
    """
    differing = sorted(name for name in new.keys() & old.keys() if new[name] != old[name])
    missing = sorted(old.keys() - new.keys())
    added = sorted(new.keys() - old.keys())
    for label, names in (("differs", differing), ("missing", missing), ("new", added)):
        for name in names:
            print(f"{label}: {name}")
    compared = len(new.keys() & old.keys())
    print(
        f"compared {compared} files: {compared - len(differing)} identical, "
        f"{len(differing)} differing, {len(missing)} missing, {len(added)} new"
    )
    return len(differing) + len(missing) + len(added)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--manifest-out", type=Path, required=True, help="manifest JSON to write")
    parser.add_argument("--against", type=Path, help="an earlier manifest to compare with")
    parser.add_argument("--workers", type=int, default=2, help="run's worker processes")
    parser.add_argument(
        "--code", type=Path, default=ROOT, help="the checkout to run (default: this script's)"
    )
    parser.add_argument("--keep", type=Path, help="copy the whole output here (a new folder)")
    args = parser.parse_args()
    if args.keep is not None and args.keep.exists():
        parser.error(f"--keep {args.keep}: exists; give a new folder")
    if not (args.code / "service" / "cli").is_dir():
        parser.error(f"--code {args.code}: no service/cli there; give an oceanlidar checkout")
    try:
        reference = json.loads(args.against.read_text())["files"] if args.against else None
    except (OSError, ValueError, KeyError) as error:
        parser.error(f"--against {args.against}: not a manifest of this script ({error})")
    code = args.code.resolve()
    with tempfile.TemporaryDirectory(prefix="identical-bytes-") as folder:
        work = Path(folder) / "work"
        work.mkdir()
        logs = Path(folder) / "logs"
        logs.mkdir()
        (work / "sweep.yaml").write_text(yaml.safe_dump(sweep(), sort_keys=False))
        run = ["run", "sweep.yaml", "--workers", str(args.workers)]
        oceanlidar(run, code=code, cwd=work, log=logs / "run.txt")
        for name, arguments in (
            ("detect", ["detect", "store.zarr", "-q"]),
            ("info", ["info", "--verify", str(work / "store.zarr")]),
        ):
            printed = oceanlidar(arguments, code=code, cwd=work, log=logs / f"{name}.log")
            (work / f"{name}.stdout.txt").write_text(printed)
        result = manifest(work)
        result["code"] = str(code)
        result["run_output"] = (logs / "run.txt").read_text()
        texts = sum(result["files"][n] != result["raw_md5"][n] for n in result["files"])
        print(
            f"{len(result['files'])} files hashed, {texts} of them printed text with {work} "
            "read as <WORK>; no metadata key dropped"
        )
        args.manifest_out.parent.mkdir(parents=True, exist_ok=True)
        args.manifest_out.write_text(json.dumps(result, indent=1, sort_keys=True) + "\n")
        if args.keep is not None:
            shutil.copytree(folder, args.keep)
    if reference is not None and compare(result["files"], reference):
        sys.exit(1)


if __name__ == "__main__":
    main()
