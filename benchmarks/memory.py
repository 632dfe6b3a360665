"""Client and scheduler memory while a sweep of 10⁶ samples is submitted.

Runs `oceanlidar run` on the embedded cluster (scheduler in the client process) for a
sweep of one million tiny samples, samples the resident memory of that process every few
seconds, then interrupts it. With bounded in-flight submission the memory must stay flat
after start-up. Usage: ``python benchmarks/memory.py [--seconds 90]``.
"""

import argparse
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import psutil

SWEEP = """\
name: million
seed: 1
realisations: 1000000
output: million.zarr
scene:
  surface: {grid_size: 16, spacing: 0.25}
  receiver: {pixels: 8, gates: [[2.0, 6.0]]}
"""


def main():
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--seconds", type=float, default=90.0)
    args = parser.parse_args()
    root = Path(__file__).resolve().parent.parent
    with tempfile.TemporaryDirectory() as folder:
        sweep = Path(folder) / "million.yaml"
        sweep.write_text(SWEEP)
        process = subprocess.Popen(
            [
                sys.executable,
                "-m",
                "service.cli",
                "run",
                str(sweep),
                "--workers",
                "2",
                "--output",
                str(Path(folder) / "million.zarr"),
            ],
            cwd=folder,
            env={**os.environ, "PYTHONPATH": str(root)},
            stdout=subprocess.DEVNULL,
            stderr=subprocess.PIPE,
            text=True,
        )
        client = psutil.Process(process.pid)
        start = time.monotonic()
        print(f"{'t (s)':>6} {'client+scheduler RSS (MiB)':>27} {'samples written':>16}")
        while time.monotonic() - start < args.seconds and process.poll() is None:
            time.sleep(5)
            rss = client.memory_info().rss / 2**20
            done = _completed(Path(folder) / "million.zarr" / "completed")
            print(f"{time.monotonic() - start:6.0f} {rss:27.0f} {done:16d}", flush=True)
        process.send_signal(signal.SIGINT)
        process.wait(timeout=120)


def _completed(folder: Path) -> int:
    """Samples marked complete: one chunk file per written sample."""
    return sum(1 for name in os.listdir(folder) if name.startswith("c")) if folder.exists() else 0


if __name__ == "__main__":
    main()
