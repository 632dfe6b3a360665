"""The PyTorch kernels against the numba ones (`kernels_torch` vs `kernels`)."""

import inspect

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from workers.backends import kernels, kernels_torch  # noqa: E402
from workers.backends.kernels import Cells  # noqa: E402

U = 2.0**-24
"""float32's unit roundoff."""

FINE, COARSE, FACTOR, BLOCK = (24, 20), (16, 14), 4, (5, 4)
"""A two-level plane: a 24 × 20 fine grid of 4 × 4 blocks from coarse cell (5, 4)."""

PLANE = Cells(
    depth=np.float32(1.5),
    origin_u=np.float32(-0.25),
    scale_u=np.float32(2.0),
    origin_v=np.float32(0.5),
    scale_v=np.float32(2.0),
    factor=np.float32(FACTOR),
    shift_v=np.float32(4.875),
    shift_u=np.float32(3.875),
)
IDENTITY = PLANE._replace(
    depth=np.float32(1.0),
    origin_u=np.float32(0.0),
    scale_u=np.float32(1.0),
    origin_v=np.float32(0.0),
    scale_v=np.float32(1.0),
)
"""The plane's map with line coordinates read as cells: ``row = base_v``, ``col = base_u``."""


DEVICES = [
    "cpu",
    pytest.param(
        "cuda", marks=pytest.mark.skipif(not torch.cuda.is_available(), reason="no CUDA device")
    ),
]


@pytest.fixture(params=DEVICES)
def device(request):
    """The device the torch kernels run on: the CPU, and CUDA where there is one."""
    return request.param


def tensors(values, device):
    """A tuple of numpy arrays as torch tensors on `device`, the same dtypes."""
    return tuple(torch.from_numpy(np.ascontiguousarray(v)).to(device) for v in values)


def random_lines(rng, n):
    """Lines crossing the plane from well off it (negative cells too) to past its far edge."""
    slope_u, slope_v = rng.normal(0, 0.3, (2, n)).astype(np.float32)
    base_u = rng.uniform(-12, 22, n).astype(np.float32)
    base_v = rng.uniform(-12, 26, n).astype(np.float32)
    return base_u, slope_u, base_v, slope_v


def edge_lines():
    """Lines at cells chosen exactly (IDENTITY map): the last row and column, just below
    them, zero, negative, NaN and coarse-only places."""
    rows, cols = FINE
    places = [
        (rows - 1, 3.5),  # last fine row: off the fine grid, onto the coarse one
        (5.25, cols - 1),  # last fine column
        (rows - 1.001, cols - 1.001),  # just inside the far corner
        (0.0, 0.0),
        (-0.001, 4.0),  # just above the first row: coarse
        (-30.0, 2.0),  # off both grids
        (40.0, 45.0),
        (np.nan, 3.0),
        (-9.0, -7.5),  # coarse only, negative
        (float(rows), float(cols)),
    ]
    row, col = np.array(places, dtype=np.float32).T
    zero = np.zeros_like(row)
    return col, zero, row, zero


def numba_splat(lines, power, cells, dtype=np.float32):
    """`kernels.splat_levels` into float32 fields, or float64 ones: the same float32
    deposits and block means summed in float64, nearly exact (a reference)."""
    fine = np.zeros(FINE, dtype)
    source = np.zeros(COARSE, dtype)
    densities = (np.float32(4.0), np.float32(0.25))
    spans = kernels.splat_levels(lines, power, cells, densities, fine, source, BLOCK)
    return fine, source, spans


def torch_splat(lines, power, cells, device):
    fine = torch.zeros(FINE, dtype=torch.float32, device=device)
    source = torch.zeros(COARSE, dtype=torch.float32, device=device)
    densities = (np.float32(4.0), np.float32(0.25))
    args = (
        tensors(lines, device),
        *tensors((power,), device),
        cells,
        densities,
        fine,
        source,
        BLOCK,
    )
    spans = kernels_torch.splat_levels(*args)
    return fine.cpu().numpy(), source.cpu().numpy(), spans


def splat_case(seed, n=400, edges=True):
    """Random lines (and the edge lines) with powers of both signs."""
    rng = np.random.default_rng(seed)
    lines = random_lines(rng, n)
    power = rng.lognormal(0, 1, n).astype(np.float32) * rng.choice([-1, 1], n)
    if edges:
        edge = edge_lines()
        # the edge lines under PLANE's map: base = cell / scale + origin - slope·depth
        base_u = edge[0] / PLANE.scale_u + PLANE.origin_u
        base_v = edge[2] / PLANE.scale_v + PLANE.origin_v
        extra = (base_u, edge[1], base_v, edge[3])
        lines = tuple(
            np.concatenate((a, b.astype(np.float32))) for a, b in zip(lines, extra, strict=True)
        )
        power = np.concatenate((power, np.full(edge[0].size, 3.0, np.float32)))
    return lines, power


def splat_tolerance(lines, power, cells=PLANE):
    """Per cell, between the numba loop and the fixed point: the numba loop's sequential
    float32 sums err by at most (k + 1)·u·Σ|t| for k terms (k <= the rays), the fixed
    point by rays · 2⁻⁶² of the largest term (4 × the largest power: the fine density)."""
    fine, source, _ = numba_splat(lines, np.abs(power), cells)
    n = power.size
    largest = 4.0 * np.abs(power).max()
    return tuple((n + 1) * U * a + n * 2.0**-62 * largest for a in (fine, source))


def exact_tolerance(lines, power, cells=PLANE):
    """Per cell, between the fixed point and the float64 reference: one float32 rounding
    of each level's sum (two on the coarse grid: its deposits, then the block mean added,
    itself rounded to float32 in both), the fixed point's resolution and the reference's
    float64 roundings (k·2⁻⁵³·Σ|t|, k <= the rays)."""
    fine, source, _ = numba_splat(lines, np.abs(power), cells, dtype=np.float64)
    n = power.size
    resolution = n * 2.0**-62 * 4.0 * np.abs(power).max()
    return tuple(
        (rounding * U + (n + 1) * 2.0**-53) * a + resolution
        for rounding, a in ((1, fine), (3, source))
    )


@pytest.mark.parametrize("seed", [0, 1, 2], ids=lambda s: f"seed{s}")
def test_splat_levels_agrees_with_numba(seed, device):
    lines, power = splat_case(seed)
    fine, source, spans = numba_splat(lines, power, PLANE)
    fine_t, source_t, spans_t = torch_splat(lines, power, PLANE, device)
    assert spans_t == spans and all(type(v) is int for v in spans_t)
    fine_tol, source_tol = splat_tolerance(lines, power)
    assert np.all(np.abs(fine_t - fine) <= fine_tol)
    assert np.all(np.abs(source_t - source) <= source_tol)
    # against the same terms summed in float64: the fixed point loses no more than its sum's
    # rounding to float32
    fine, source, _ = numba_splat(lines, power, PLANE, dtype=np.float64)
    fine_tol, source_tol = exact_tolerance(lines, power)
    assert np.all(np.abs(fine_t - fine) <= fine_tol)
    assert np.all(np.abs(source_t - source) <= source_tol)
    assert np.count_nonzero(fine) > 50 and np.count_nonzero(source) > 50


def test_splat_levels_edge_rules(device):
    """The last row and column go to the coarse grid, NaN and off-grid lines vanish."""
    lines = edge_lines()
    power = np.arange(1, lines[0].size + 1, dtype=np.float32)
    fine, source, spans = numba_splat(lines, power, IDENTITY)
    fine_t, source_t, spans_t = torch_splat(lines, power, IDENTITY, device)
    assert spans_t == spans
    np.testing.assert_allclose(fine_t, fine, rtol=4 * U, atol=0)
    np.testing.assert_allclose(source_t, source, rtol=4 * U, atol=0)


def test_splat_levels_with_no_ray_on_the_fine_grid(device):
    lines = tuple(np.array(v, np.float32) for v in ([-20.0, -9.0], [0, 0], [-3.0, 30.0], [0, 0]))
    power = np.ones(2, np.float32)
    fine, source, spans = numba_splat(lines, power, IDENTITY)
    fine_t, source_t, spans_t = torch_splat(lines, power, IDENTITY, device)
    assert spans_t == spans and not fine_t.any() and not fine.any()
    np.testing.assert_array_equal(source_t, source)
    empty = tuple(np.zeros(0, np.float32) for _ in range(4))
    assert torch_splat(empty, np.zeros(0, np.float32), PLANE, device)[2] == (0, 0, 0, 0)


@pytest.mark.parametrize("bad", [np.nan, np.inf])
def test_splat_levels_a_non_finite_power_is_not_lost(device, bad):
    """Fixed point cannot hold a NaN or an infinity: the fields say so (NaN), so that the
    sample is refused, not written with that ray's light silently dropped."""
    lines, power = splat_case(5, edges=False)
    power[17] = bad
    fine, source, _ = torch_splat(lines, power, PLANE, device)
    assert np.isnan(fine).all() and np.isnan(source).all()


def test_splat_levels_same_bytes_twice_and_whatever_the_rays_order(device):
    lines, power = splat_case(7, n=3000)
    first = torch_splat(lines, power, PLANE, device)
    again = torch_splat(lines, power, PLANE, device)
    order = np.random.default_rng(3).permutation(power.size)
    permuted = torch_splat(tuple(a[order] for a in lines), power[order], PLANE, device)
    for other in (again, permuted):
        assert other[0].tobytes() == first[0].tobytes()
        assert other[1].tobytes() == first[1].tobytes()
        assert other[2] == first[2]


def test_splat_levels_coarse_rows_of_the_fine_grid_alone(device):
    """With every ray on the fine grid, the coarse rows are those of its blocks."""
    rng = np.random.default_rng(4)
    row = rng.uniform(5.5, 13.0, 50).astype(np.float32)
    col = rng.uniform(2.0, 17.0, 50).astype(np.float32)
    zero = np.zeros_like(row)
    lines, power = (col, zero, row, zero), rng.uniform(1, 2, 50).astype(np.float32)
    fine, source, spans = numba_splat(lines, power, IDENTITY)
    assert spans[2:] == (BLOCK[0] + 1, BLOCK[0] + 4)
    fine_t, source_t, spans_t = torch_splat(lines, power, IDENTITY, device)
    assert spans_t == spans
    tolerances = splat_tolerance(lines, power, cells=IDENTITY)
    assert np.all(np.abs(fine_t - fine) <= tolerances[0])
    assert np.all(np.abs(source_t - source) <= tolerances[1])


def lift():
    """The fine cells' lower coarse cells and weights, as `workers.fast.spread.Levels.lift`."""
    axes = []
    for size, shift in ((FINE[0], PLANE.shift_v), (FINE[1], PLANE.shift_u)):
        position = np.arange(size, dtype=np.float32) / np.float32(FACTOR) + shift
        lower = np.floor(position).astype(np.intp)
        axes.append((lower, (position - lower).astype(np.float32)))
    return tuple(axes)


def gather_case(seed, *, tail, shadowed):
    """Lines and a plane's random light: ``(lines, parts, lit)`` for `gather_levels`."""
    rng = np.random.default_rng(seed)
    lines, _ = splat_case(seed, n=500)
    window = kernels.reach(lines, PLANE, FINE, COARSE)[:4]
    near = rng.normal(size=(window[1] - window[0], FINE[1])).astype(np.float32)
    far = rng.normal(size=COARSE).astype(np.float32)
    none = np.zeros((0, 0), np.float32)
    tails = tuple(rng.normal(size=s).astype(np.float32) for s in (FINE, COARSE))
    lit = rng.uniform(size=FINE).astype(np.float32) if shadowed else none
    return lines, (near, window, far, tails if tail else (none, none)), lit


def torch_parts(parts, device):
    """`gather_levels`' parts and lift (`lift`) as tensors on `device`."""
    near, window, far, tails = parts
    parts_t = (*tensors((near,), device), window, *tensors((far,), device), tensors(tails, device))
    return parts_t, tuple(tensors(axis, device) for axis in lift())


@pytest.mark.parametrize("tail", [True, False], ids=["tail", "no-tail"])
@pytest.mark.parametrize("shadowed", [True, False], ids=["shadowed", "all-lit"])
def test_gather_levels_agrees_with_numba(tail, shadowed, device):
    lines, parts, lit = gather_case(13, tail=tail, shadowed=shadowed)
    _, _, far, tails = parts
    rng = np.random.default_rng(5)
    weight = rng.uniform(0.5, 2, lines[0].size).astype(np.float32)
    out = rng.normal(size=lines[0].size).astype(np.float32)
    initial, out_t = out.copy(), torch.from_numpy(out.copy()).to(device)
    kernels.gather_levels(lines, PLANE, FINE, parts, lift(), lit, (weight,), (out,))
    args = (
        tensors(lines, device),
        PLANE,
        FINE,
        *torch_parts(parts, device),
        *tensors((lit,), device),
        tensors((weight,), device),
        (out_t,),
    )
    kernels_torch.gather_levels(*args)
    # elementwise float32 in the same order: a few roundings of values of size ~ the sum of
    # the magnitudes that enter a pixel (fields ~1, 4 corners, 3 terms a cell, weight <= 2)
    np.testing.assert_allclose(out_t.cpu().numpy(), out, rtol=0, atol=64 * U * 4 * 3 * 2)
    edge = lines[0].size - 10
    # the edge lines off both grids (far off, past the coarse columns, NaN) add nothing
    off = edge + np.array([5, 6, 7])
    assert out_t.cpu().numpy()[off].tobytes() == initial[off].tobytes()
    assert out[off].tobytes() == initial[off].tobytes()
    # those off the fine grid only (its last row and column, above it, coarse only) read
    # the far spread and the tail's far part at their coarse place, all their light kept
    coarse = edge + np.array([0, 1, 4, 8, 9])
    read = far + tails[1] if tail else far
    expected = initial[coarse] + weight[coarse] * far_at(read, lines, coarse)
    np.testing.assert_allclose(out[coarse], expected, rtol=1e-5, atol=1e-6)
    assert np.all(out[coarse] != initial[coarse])


@pytest.mark.parametrize("tail", [True, False], ids=["tail", "no-tail"])
@pytest.mark.parametrize("shadowed", [True, False], ids=["shadowed", "all-lit"])
def test_one_gather_of_several_outputs_is_their_gathers_apart(tail, shadowed, device):
    # issue #39 item 1: a gate's image and its target-free twin (and any more outputs)
    # read in one pass give each output the bytes of its own gather: the last keeps `lit`,
    # the others all the light
    lines, parts, lit = gather_case(17, tail=tail, shadowed=shadowed)
    none = np.zeros((0, 0), np.float32)
    rng = np.random.default_rng(3)
    weights = tuple(rng.uniform(0.5, 2, (3, lines[0].size)).astype(np.float32))
    start = tuple(rng.normal(size=(3, lines[0].size)).astype(np.float32))
    apart = tuple(o.copy() for o in start)
    for k in range(3):
        kept = lit if k == 2 else none
        kernels.gather_levels(
            lines, PLANE, FINE, parts, lift(), kept, weights[k : k + 1], apart[k : k + 1]
        )
    together = tuple(o.copy() for o in start)
    kernels.gather_levels(lines, PLANE, FINE, parts, lift(), lit, weights, together)
    for k in range(3):
        assert together[k].tobytes() == apart[k].tobytes()
        assert not np.array_equal(together[k], start[k])
    if shadowed:  # the shadow reaches the last output only
        assert not np.array_equal(
            together[2] - start[2], (together[1] - start[1]) * (weights[2] / weights[1])
        )
    # the torch kernel: the same, to the bit, against its own gathers apart
    parts_t, lift_t = torch_parts(parts, device)
    lines_t, weights_t = tensors(lines, device), tensors(weights, device)
    apart_t, together_t = tensors(start, device), tensors(start, device)
    for k in range(3):
        kept = tensors((lit if k == 2 else none,), device)[0]
        args = (lines_t, PLANE, FINE, parts_t, lift_t, kept, weights_t[k : k + 1])
        kernels_torch.gather_levels(*args, apart_t[k : k + 1])
    lit_t = tensors((lit,), device)[0]
    kernels_torch.gather_levels(
        lines_t, PLANE, FINE, parts_t, lift_t, lit_t, weights_t, together_t
    )
    for k in range(3):
        assert together_t[k].cpu().numpy().tobytes() == apart_t[k].cpu().numpy().tobytes()


def far_at(field, lines, index):
    """A coarse field at lines' crossings of PLANE, bilinearly, in float64 (a reference)."""
    fine_row, fine_col = (
        (lines[2 * k][index] + lines[2 * k + 1][index] * 1.5 - origin) * 2.0
        for k, origin in ((1, 0.5), (0, -0.25))
    )
    row = fine_row / FACTOR + float(PLANE.shift_v)
    col = fine_col / FACTOR + float(PLANE.shift_u)
    r, c = np.floor(row).astype(int), np.floor(col).astype(int)
    down, right = row - r, col - c
    return (
        field[r, c] * (1 - down) * (1 - right)
        + field[r, c + 1] * (1 - down) * right
        + field[r + 1, c] * down * (1 - right)
        + field[r + 1, c + 1] * down * right
    )


@pytest.mark.parametrize("edges", [True, False], ids=["edges", "random"])
def test_reach_agrees_with_numba_and_with_the_lines_cells(edges, device):
    lines = splat_case(19, n=60, edges=edges)[0]
    found = kernels.reach(lines, PLANE, FINE, COARSE)
    assert kernels_torch.reach(tensors(lines, device), PLANE, FINE, COARSE) == found
    # the fine cells the lines touch, and the coarse rows those off the fine grid touch on
    # the coarse one, found in float64
    fine_row = (lines[2] + lines[3] * 1.5 - 0.5) * 2.0
    fine_col = (lines[0] + lines[1] * 1.5 + 0.25) * 2.0
    on_fine = (fine_row >= 0) & (fine_col >= 0) & (fine_row < FINE[0] - 1)
    on_fine &= fine_col < FINE[1] - 1
    rows, cols = np.floor(fine_row[on_fine]).astype(int), np.floor(fine_col[on_fine]).astype(int)
    window = (rows.min(), rows.max() + 2, cols.min(), cols.max() + 2)
    row = fine_row / FACTOR + float(PLANE.shift_v)
    col = fine_col / FACTOR + float(PLANE.shift_u)
    on_coarse = (row >= 0) & (col >= 0) & (row < COARSE[0] - 1) & (col < COARSE[1] - 1)
    touched = np.floor(row[on_coarse & ~on_fine]).astype(int)
    assert found == (*window, touched.min(), touched.max() + 2)
    # no line on the fine grid, none off it on the coarse one: zeros
    off = tuple(np.array(v, np.float32) for v in ([-50.0], [0.0], [-50.0], [0.0]))
    assert kernels_torch.reach(tensors(off, device), PLANE, FINE, COARSE) == (0,) * 6
    assert kernels.reach(off, PLANE, FINE, COARSE) == (0,) * 6
    inside = tuple(np.array(v, np.float32) for v in ([2.0], [0.0], [3.0], [0.0]))
    assert kernels.reach(inside, PLANE, FINE, COARSE)[4:] == (0, 0)


def test_sample_agrees_with_numba(device):
    rng = np.random.default_rng(8)
    lines, _ = splat_case(17, n=20_000)  # lines on every cell of the box's edges
    fields = tuple(rng.normal(size=FINE).astype(np.float32) for _ in range(2))
    for box in ((0, FINE[0], 0, FINE[1]), (6, 13, 3, 9)):
        out = np.full((2, lines[0].size), np.nan, np.float32)
        out_t = torch.full((2, lines[0].size), np.nan, device=device)
        kernels.sample(lines, PLANE, fields, box, out)
        kernels_torch.sample(tensors(lines, device), PLANE, tensors(fields, device), box, out_t)
        np.testing.assert_allclose(out_t.cpu().numpy(), out, rtol=0, atol=16 * U * 4)
        assert np.count_nonzero(out == 0) > 10


def periodic_grid(rng, n, fields=3):
    """``fields`` N × N periodic fields with their first row and column repeated, flattened."""
    values = rng.normal(size=(fields, n, n)).astype(np.float32)
    wrapped = np.concatenate((values, values[:, :1]), axis=1)
    wrapped = np.concatenate((wrapped, wrapped[:, :, :1]), axis=2)
    return wrapped.reshape(fields, -1)


def test_bilinear_sum_agrees_with_numba_on_periodic_grids_of_any_size(device):
    rng = np.random.default_rng(9)
    sizes = (16, 12, 7)  # a power of two (bit mask) and two others (remainder)
    grids = tuple(periodic_grid(rng, n) for n in sizes)
    inverses = (np.float32(1 / 0.3), np.float32(1 / 1.7), np.float32(1 / 5.0))
    x = rng.uniform(-200, 200, 2000)  # float64, negative coordinates too
    y = rng.uniform(-200, 200, 2000)
    out = np.empty((3, x.size), np.float32)
    kernels.bilinear_sum(grids, sizes, inverses, x, y, out)
    out_t = torch.empty((3, x.size), device=device)
    kernels_torch.bilinear_sum(
        tensors(grids, device), sizes, inverses, *tensors((x, y), device), out_t
    )
    # each grid's value ~ its field's magnitude (< 5), three grids added in float32
    np.testing.assert_allclose(out_t.cpu().numpy(), out, rtol=0, atol=3 * 8 * U * 5)


def test_cell_uniforms_are_bit_exact(device):
    rng = np.random.default_rng(10)
    x = np.concatenate((rng.uniform(-1e4, 1e4, 5000), [0.0, -0.0, -1e-9, 3.2e7]))
    y = np.concatenate((rng.uniform(-1e4, 1e4, 5000), [0.0, 1e-9, -7.0, -3.2e7]))
    for key, frame in ((np.uint64(2**64 - 5), np.uint64(3)), (np.uint64(12345), np.uint64(0))):
        first, second = (np.empty(x.size, np.float32) for _ in range(2))
        kernels.cell_uniforms(x, y, np.float32(1 / 0.016), key, frame, first, second)
        first_t, second_t = (torch.empty(x.size, device=device) for _ in range(2))
        kernels_torch.cell_uniforms(
            *tensors((x, y), device), np.float32(1 / 0.016), key, frame, first_t, second_t
        )
        assert first_t.cpu().numpy().tobytes() == first.tobytes()
        assert second_t.cpu().numpy().tobytes() == second.tobytes()


def test_column_convolution_agrees_with_numba(device):
    rng = np.random.default_rng(12)
    n, k = 13, 9
    kernel = (rng.normal(size=(n, k)) + 1j * rng.normal(size=(n, k))).astype(np.complex64)
    rows = (rng.normal(size=(4, k)) + 1j * rng.normal(size=(4, k))).astype(np.complex64)
    out = (rng.normal(size=(6, k)) + 1j * rng.normal(size=(6, k))).astype(np.complex64)
    out_t = torch.from_numpy(out.copy()).to(device)
    kernels.column_convolution(kernel, rows, 11, 2, out)
    kernels_torch.column_convolution(*tensors((kernel, rows), device), 11, 2, out_t)
    # 4 complex products (|.| < ~25) added to out in order: a few roundings each
    np.testing.assert_allclose(out_t.cpu().numpy(), out, rtol=0, atol=5 * 4 * 8 * U * 25)


def test_both_kernel_modules_expose_the_same_names_and_signatures():
    # issue #39 item 2: a stage calls `Backend.kernels` the same way on either backend
    assert sorted(kernels.__all__) == sorted(kernels_torch.__all__)
    for name in kernels.__all__:
        compiled, vectorised = getattr(kernels, name), getattr(kernels_torch, name)
        if name == "Cells":
            assert vectorised is compiled
            continue
        python = getattr(compiled, "py_func", compiled)
        assert inspect.signature(vectorised) == inspect.signature(python), name
