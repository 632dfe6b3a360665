"""Batched samples per second on PyTorch (issue #28): the render, its FFT floor, a run.

Three figures, measured in one run on one device (CUDA if torch sees one, else the CPU, and
it says so):

1. Six-gate samples per second of the batched render (`service.tasks.render_samples`, the
   call a run's task makes: `workers.render.render_batch` on the torch backend) at 256² and
   512² pixels, a batch of ``--batch`` samples of one scene (a shard's), timed after a warm-up
   batch (the scene's setup cached, as in a run). Each batch is rendered twice and its bytes
   compared: the figure is of deterministic samples (no float atomics; the same seed, the
   same bytes).
2. Beside it, the FFT-only floor: the same batch's rfft2 + irfft2 pairs of the render's
   planes (float32; the fine level of each gate's plane and the target's, their sizes read
   from the scene's first frame, `workers.fast.planes.frame_geometry`), one pair a plane and a
   sample, batched over the samples: the most samples per second the spreads' FFTs allow.
3. End to end: ``oceanlidar run --device cuda`` into a local store, 128 pixels, six gates,
   ``--samples`` samples (dask-cuda's LocalCUDACluster, one worker a GPU): samples per second
   as the run reports them (rendering and writing, after the cluster's start), and the wall
   clock of the whole command. Skipped, with a line, without CUDA.

Times are wall-clock, with the device synchronised (CUDA) before each clock read; medians
of ``--rounds``, the render and the FFT floor interleaved round by round. Usage, from the
repository root: ``python -m benchmarks.gpu [--sizes 256 512] [--batch 64] [--rounds 7]
[--samples 4096]``.

On the shared 2-core machine without a GPU (2026-11-25, load 2-4, batches of 2, 5 rounds):
torch on the CPU through P1's in-progress `render_batch` (its samples one by one) 4.1
samples/s at 256², 1.2 at 512², its FFT floor beside 401 and 90 (an earlier run, not
interleaved: 0.5 and 0.2, floor 286 and 39). In a process whose render ran on numpy (numba)
first, torch's CPU FFT floor reads 7-19 samples/s: compare CPU figures within one run.

Issue #28's targets on an H100: at least 4,000 samples/s at 256² (aim 10,000), 1,000/s at
512², a run end to end at least 2,000 samples/s at 128 px. Figures measured so far are in
the closing note of issue #28 (this script prints them; it asserts nothing).
"""

import argparse
import os
import re
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import torch

from service.devices import choose
from service.tasks import render_samples
from workers.fast.planes import frame_geometry
from workers.settings.scene import Scene
from workers.settings.seeds import SampleSeed
from workers.setup.builder import scene_setup

ROOT = Path(__file__).resolve().parent.parent


def scene(n):
    """The six-gate (ML(DC)) benchmark scene of `n`² pixels: a 0.3 m sphere at 5 m."""
    return Scene.model_validate(
        {
            "surface": {"grid_size": n, "spacing": 4.1 / n},
            "target": {"shape": "sphere"},
            "receiver": {"pixels": n},
            "radiometry": {"mode": "normalised", "white_plane_photons": 13.0},
        }
    )


def synchronised(device):
    """A clock read after the device's queued work has finished."""
    if device.startswith("cuda"):
        torch.cuda.synchronize()
    return time.perf_counter()


def plane_shapes(s):
    """The fine grids' shapes of the first frame's planes (gates', target's), cells."""
    geometry = frame_geometry(scene_setup(s), 0)
    planes = [*geometry.gate_planes, geometry.target_plane]
    return [plane.levels.fine.shape for plane in planes if plane is not None]


def fft_pairs(shapes, device, batch):
    """One rfft2 + irfft2 pair a plane of `shapes`, batched over `batch` samples: a callable."""
    generator = torch.Generator(device=device).manual_seed(0)
    planes = [
        torch.randn((batch, *shape), generator=generator, device=device, dtype=torch.float32)
        for shape in shapes
    ]

    def pairs():
        for plane in planes:
            torch.fft.irfft2(torch.fft.rfft2(plane), s=plane.shape[-2:])

    return pairs


def measure(s, backend, batch, rounds):
    """Median samples/s of the batched render and of its FFT floor, interleaved round by
    round (a shared machine's load disturbs both alike), and whether the render's bytes
    were the same every time."""
    seeds = [SampleSeed(root=7, point=0, realisation=r) for r in range(batch)]
    pairs = fft_pairs(plane_shapes(s), backend.device, batch)
    first = render_samples(s, seeds, backend=backend)  # the warm-up: setup cached
    pairs()
    renders, floors, same = [], [], True
    for _ in range(rounds):
        start = synchronised(backend.device)
        again = render_samples(s, seeds, backend=backend)
        renders.append(synchronised(backend.device) - start)
        same &= all(first[name].tobytes() == again[name].tobytes() for name in first)
        start = synchronised(backend.device)
        pairs()
        floors.append(synchronised(backend.device) - start)
    return batch / statistics.median(renders), batch / statistics.median(floors), same


SWEEP = """\
name: gpu-benchmark
seed: 7
realisations: {samples}
output: bench.zarr
scene:
  surface: {{grid_size: 128, spacing: 0.032}}
  target: {{shape: sphere, radius: 0.3, depth: 5.0}}
  receiver: {{pixels: 128, gates: mldc}}
  radiometry: {{mode: normalised, white_plane_photons: 200.0}}
"""


def end_to_end(samples):
    """``oceanlidar run --device cuda`` of `samples` 128-pixel samples: (run's rate, wall s)."""
    with tempfile.TemporaryDirectory() as folder:
        (Path(folder) / "sweep.yaml").write_text(SWEEP.format(samples=samples))
        command = [sys.executable, "-m", "service.cli", "run", "sweep.yaml", "--device", "cuda"]
        env = {**os.environ, "PYTHONPATH": str(ROOT)}
        start = time.perf_counter()
        done = subprocess.run(command, cwd=folder, env=env, capture_output=True, text=True)
        wall = time.perf_counter() - start
    if done.returncode != 0:
        raise SystemExit(f"oceanlidar run failed ({done.returncode}):\n{done.stderr[-2000:]}")
    rate = re.search(r"\(([0-9.]+) samples/s\)", done.stderr)
    return float(rate.group(1)), wall


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", type=int, nargs="+", default=[256, 512])
    parser.add_argument("--batch", type=int, default=None, help="default 64 on CUDA, 4 on CPU")
    parser.add_argument("--rounds", type=int, default=7)
    parser.add_argument("--samples", type=int, default=4096, help="of the end-to-end run")
    args = parser.parse_args()
    cuda = torch.cuda.is_available()
    device = "cuda" if cuda else "cpu"
    backend = choose("torch", device)
    batch = args.batch or (64 if cuda else 4)
    name = torch.cuda.get_device_name() if cuda else "no CUDA device here: torch on the CPU"
    print(f"device: {device} ({name}); torch {torch.__version__}; batches of {batch} samples")
    print("pixels  render samples/s  same bytes  FFT floor samples/s  planes (fine cells)")
    for n in args.sizes:
        s = scene(n)
        rate, floor, same = measure(s, backend, batch, args.rounds)
        sizes = ", ".join(f"{a}x{b}" for a, b in plane_shapes(s))
        print(f"{n:>6}  {rate:>16.1f}  {'yes' if same else 'NO':>10}  {floor:>19.1f}  {sizes}")
    if not cuda:
        print("end to end (oceanlidar run --device cuda, 128 px): skipped, no CUDA device")
        return
    rate, wall = end_to_end(args.samples)
    print(
        f"end to end (oceanlidar run --device cuda, 128 px, {args.samples} samples): "
        f"{rate:.1f} samples/s as the run reports it, {args.samples / wall:.1f} over the "
        f"command's {wall:.1f} s wall clock"
    )


if __name__ == "__main__":
    main()
