"""How fast are the PyTorch kernels against the numba ones? (issue #28)

Times each kernel of `workers.backends.kernels` (numba, sequential) and of
`workers.backends.kernels_torch`
(on the CPU with ``--threads`` threads, and on CUDA where there is a device) on one
sample's sizes: a 512 × 512 ray lattice splatted on a 768² fine grid (4 × 4 blocks on a
384² coarse grid), 256 × 256 lines of sight gathered, the sea's three cascades sampled at
every ray, the sub-grid cells hashed, eight rows convolved along 384-row columns. Prints
the median time of a call, ms.

Usage, from the repository root: ``python -m benchmarks.kernels_torch [--repeats 5]
[--threads 1]``.
"""

import argparse
import statistics
import time

import numpy as np
import torch

from workers.backends import kernels, kernels_torch
from workers.backends.kernels import Cells

FINE, COARSE, FACTOR, BLOCK = (768, 768), (384, 384), 4, (96, 96)
CELLS = Cells(
    depth=np.float32(3.0),
    origin_u=np.float32(-10.0),
    scale_u=np.float32(38.4),
    origin_v=np.float32(-10.0),
    scale_v=np.float32(38.4),
    factor=np.float32(FACTOR),
    shift_v=np.float32(96.0 - 0.375),
    shift_u=np.float32(96.0 - 0.375),
)


def kernel_calls(rng, module, t):
    """Each kernel's call on its inputs, made by `t` (numpy to the backend) once, here."""
    rays = 512 * 512
    base = rng.uniform(-12, 12, (2, rays)).astype(np.float32)
    slope = rng.normal(0, 0.05, (2, rays)).astype(np.float32)
    lines = (base[0], slope[0], base[1], slope[1])
    sights = tuple(a[:65536] * np.float32(0.8) for a in lines)
    power = rng.lognormal(0, 1, rays).astype(np.float32)
    position = np.arange(FINE[0], dtype=np.float32) / FACTOR + CELLS.shift_v
    lower = np.floor(position).astype(np.intp)
    axis = (lower, (position - lower).astype(np.float32))
    window = kernels.reach(sights, CELLS, FINE, COARSE)[:4]
    near = rng.normal(size=(window[1] - window[0], FINE[1])).astype(np.float32)
    far = rng.normal(size=COARSE).astype(np.float32)
    none = np.zeros((0, 0), np.float32)
    grids = tuple(rng.normal(size=(3, 513 * 513)).astype(np.float32) for _ in range(3))
    x, y = rng.uniform(-50, 50, (2, rays))
    kernel = (rng.normal(size=(384, 193)) + 1j * rng.normal(size=(384, 193))).astype(np.complex64)
    rows = kernel[:8].copy()
    lines, sights, power, near, far, none = t((lines, sights, power, near, far, none))
    fine, source = t((np.zeros(FINE, np.float32), np.zeros(COARSE, np.float32)))
    densities = (np.float32(4.0), np.float32(0.25))
    lift, weight, out = t(((axis, axis), np.ones(65536, np.float32), np.zeros(65536, np.float32)))
    grids, x, y = t((grids, x, y))
    sums, first, second = t((np.empty((3, x.shape[0]), np.float32), *np.empty((2, rays), "f4")))
    inverses = (np.float32(5.0), np.float32(1.0), np.float32(0.2))
    kernel, rows, mixed = t((kernel, rows, np.zeros((8, 193), np.complex64)))
    parts = (near, window, far, (none, none))
    key, frame = np.uint64(12345), np.uint64(3)
    return {
        "splat_levels": lambda: module.splat_levels(
            lines, power, CELLS, densities, fine, source, BLOCK
        ),
        "reach": lambda: module.reach(sights, CELLS, FINE, COARSE),
        "gather_levels": lambda: module.gather_levels(
            sights, CELLS, FINE, parts, lift, none, (weight,), (out,)
        ),
        "bilinear_sum": lambda: module.bilinear_sum(grids, (512,) * 3, inverses, x, y, sums),
        "cell_uniforms": lambda: module.cell_uniforms(
            x, y, np.float32(60.0), key, frame, first, second
        ),
        "column_convolution": lambda: module.column_convolution(kernel, rows, 40, 36, mixed),
    }


def converter(device):
    """Numpy arrays (nested in tuples) to tensors on `device`; None: kept as numpy."""

    def convert(values):
        if isinstance(values, tuple):
            return tuple(convert(v) for v in values)
        if device is None:
            return values
        return torch.from_numpy(np.ascontiguousarray(values)).to(device)

    return convert


def timed(call, repeats, device):
    """Median seconds of `call()` over `repeats` runs after a warm-up one."""
    call()
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        call()
        if device == "cuda":
            torch.cuda.synchronize()
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--threads", type=int, default=1, help="torch's CPU threads")
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    targets = [("numba", kernels, None), (f"torch cpu ×{args.threads}", kernels_torch, "cpu")]
    if torch.cuda.is_available():
        targets.append(("torch cuda", kernels_torch, "cuda"))
    columns = {}
    for name, module, device in targets:
        calls = kernel_calls(np.random.default_rng(0), module, converter(device))
        columns[name] = {k: timed(call, args.repeats, device) * 1e3 for k, call in calls.items()}
    print(f"{'kernel (ms a call)':20s}" + "".join(f"{name:>18s}" for name in columns))
    for kernel in next(iter(columns.values())):
        print(f"{kernel:20s}" + "".join(f"{c[kernel]:18.2f}" for c in columns.values()))


if __name__ == "__main__":
    main()
