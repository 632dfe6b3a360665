"""Detectors and detection metrics: closed forms, then a real sweep through the CLI."""

import re
import shutil

import numpy as np
import pytest
import xarray as xr
import zarr
from conftest import TINY_SCENE, cf_failures, on_cluster, same_values
from scipy.stats import multivariate_normal, norm, poisson

import service.charts
import service.plots
from service.cli import main
from service.dataset import open_dataset
from service.detect import pair_points
from service.errors import InputError
from service.store.location import Store, consolidated_v3
from service.store.shards import sample_checksum, sample_identity
from service.store.template import create_store
from service.sweep import parse_sweep
from workers.dataset.variables import rendered_order
from workers.detectors.detection import (
    DETECTORS,
    _auc_rows,
    _resampled_aucs,
    auc,
    bootstrap_auc,
    fit_logistic,
    ideal_observer,
    pd_at_pfa,
    roc_curve,
    score_metrics,
)
from workers.detectors.marginal import sea_marginal_observer


def rng(seed):
    return np.random.Generator(np.random.PCG64(seed))


@pytest.mark.parametrize("decimals", [None, 1], ids=["distinct", "tied"])
def test_the_bootstraps_aucs_are_those_of_the_ranks_to_the_bit(decimals):
    # the bootstrap sorts the scores once and counts each resample's copies instead of
    # ranking each resample (`scipy.stats.rankdata`): the same AUCs, bit for bit, ties too
    r = rng(3)
    s1, s0 = r.normal(1.0, 1.0, 150), r.normal(0.0, 1.0, 150)
    if decimals is not None:
        s1, s0 = np.round(s1, decimals), np.round(s0, decimals)
    picks = r.integers(0, 150, size=(300, 150))
    ranked = _auc_rows(s1[picks], s0[picks])
    assert _resampled_aucs(s1, s0, picks).tobytes() == ranked.tobytes()
    s1[7] = np.nan  # no order: NaN, as the ranks give
    assert np.isnan(bootstrap_auc(positives=s1, negatives=s0)).all()


def binormal_auc_se(separation, n):
    """Exact standard error of the Mann–Whitney AUC of n N(d, 1) against n N(0, 1) scores.

    Var = [A(1 - A) + 2 (n - 1)(Q - A²)] / n² (Hanley & McNeil 1982, eq. 1, exact form),
    with Q = P(X > Y, X > Y') = P(X > Y, X' > Y): a bivariate normal of correlation 1/2
    at (d/√2, d/√2).
    """
    area = norm.cdf(separation / np.sqrt(2))
    pair = multivariate_normal(mean=[0, 0], cov=[[1, 0.5], [0.5, 1]]).cdf(
        [separation / np.sqrt(2)] * 2
    )
    return np.sqrt((area * (1 - area) + 2 * (n - 1) * (pair - area**2)) / n**2)


@pytest.mark.parametrize("separation", [0.5, 1.0, 2.0], ids=["d0.5", "d1", "d2"])
def test_auc_of_two_gaussian_classes_is_phi_of_d_over_root_2(separation):
    n = 2000
    draws = rng(1)
    negatives = draws.normal(0.0, 1.0, n)
    positives = draws.normal(separation, 1.0, n)
    exact = norm.cdf(separation / np.sqrt(2))
    low, high = bootstrap_auc(positives=positives, negatives=negatives)
    assert low <= exact <= high
    assert low <= auc(positives=positives, negatives=negatives) <= high
    # the interval is as wide as the AUC's sampling law says, 2 x 1.96 SE: its width varies
    # by ~2 % from the 2000 resamples' quantiles and ~2 % from the SE's own sampling error
    # at n = 2000, so 10 % is 4 sigma (a 90 % interval, 16 % narrower, fails)
    width = high - low
    assert width == pytest.approx(2 * 1.96 * binormal_auc_se(separation, n), rel=0.1)


def test_auc_counts_ties_as_half_and_swapped_classes_as_complement():
    assert auc(positives=[1.0, 1.0], negatives=[1.0, 1.0]) == 0.5
    assert auc(positives=[2.0, 3.0], negatives=[0.0, 1.0]) == 1.0
    s1, s0 = rng(2).normal(0.7, 1, 300), rng(3).normal(0, 1, 300)
    assert auc(positives=s0, negatives=s1) == pytest.approx(1 - auc(positives=s1, negatives=s0))


def test_pd_at_pfa_of_gaussian_classes_matches_the_closed_form():
    n, separation = 20000, 2.0
    draws = rng(4)
    negatives = draws.normal(0.0, 1.0, n)
    positives = draws.normal(separation, 1.0, n)
    for alpha in (1e-1, 1e-2):
        threshold = norm.isf(alpha)
        exact = norm.sf(threshold - separation)
        # binomial error of the positives above the threshold, plus the threshold's own
        # (quantile of n negatives) carried through the positives' density
        slope = norm.pdf(threshold - separation) / norm.pdf(threshold)
        se = np.sqrt(exact * (1 - exact) / n + slope**2 * alpha * (1 - alpha) / n)
        estimate = pd_at_pfa(positives=positives, negatives=negatives, pfa=alpha)
        assert estimate == pytest.approx(exact, abs=4 * se)


def test_pd_at_pfa_is_unavailable_without_enough_negatives():
    draws = rng(5)
    positives = draws.normal(1.0, 1.0, 1000)
    assert np.isnan(pd_at_pfa(positives=positives, negatives=draws.normal(size=199), pfa=1e-2))
    assert np.isfinite(pd_at_pfa(positives=positives, negatives=draws.normal(size=200), pfa=1e-2))
    assert np.isnan(pd_at_pfa(positives=positives, negatives=draws.normal(size=19), pfa=1e-1))


def test_ideal_observer_is_the_poisson_log_likelihood_ratio():
    draws = rng(6)
    background = draws.uniform(0.0, 3.0, (50, 2, 3, 4))
    signal = background * draws.uniform(0.5, 2.0, background.shape)
    signal[:, 0, 0, 0] = background[:, 0, 0, 0]  # unchanged pixels count for nothing
    counts = draws.poisson(signal)
    oracle = (poisson.logpmf(counts, signal) - poisson.logpmf(counts, background)).sum(
        axis=(1, 2, 3)
    )
    np.testing.assert_allclose(
        ideal_observer(counts, signal=signal, background=background), oracle, rtol=1e-12
    )
    # a count where the background cannot make one is certain evidence of the target
    zero = np.zeros((1, 1))
    assert ideal_observer(np.ones((1, 1)), signal=zero + 1, background=zero) == np.inf


def test_ideal_observer_roc_of_one_poisson_pixel_is_the_exact_one():
    """One pixel, λ0 = 2, λ1 = 5: the LLR grows with the count, so the test "LLR ≥ t" is
    "x ≥ k" and its ROC vertices are (P(X0 ≥ k), P(X1 ≥ k)), k = 0, 1, ..."""
    n, lam0, lam1 = 5000, 2.0, 5.0
    draws = rng(7)
    x0 = draws.poisson(lam0, (n, 1))
    x1 = draws.poisson(lam1, (n, 1))
    means = {"signal": np.full((n, 1), lam1), "background": np.full((n, 1), lam0)}
    s0 = ideal_observer(x0, **means)
    s1 = ideal_observer(x1, **means)
    pfa, pd = roc_curve(positives=s1, negatives=s0)
    # vertex j (after the origin) is the threshold at the j-th largest distinct count
    counts = np.unique(np.concatenate([x0, x1]))[::-1]
    exact_pfa, exact_pd = poisson.sf(counts - 1, lam0), poisson.sf(counts - 1, lam1)
    for estimate, exact in ((pfa[1:], exact_pfa), (pd[1:], exact_pd)):
        se = np.sqrt(exact * (1 - exact) / n) + 1 / n
        assert np.all(np.abs(estimate - exact) <= 5 * se)
    k = np.arange(60)
    exact_auc = np.sum(
        poisson.pmf(k, lam1) * (poisson.cdf(k - 1, lam0) + poisson.pmf(k, lam0) / 2)
    )
    low, high = bootstrap_auc(positives=s1, negatives=s0)
    assert low <= exact_auc <= high


def test_ideal_observer_auc_of_two_poisson_pixels_is_the_exact_one():
    """Two pixels whose means move apart (1, 3) -> (2, 2): the LLR x1 ln 2 + x2 ln(2/3) is
    not a function of the total; its law under each hypothesis, by enumeration, gives the
    exact AUC."""
    n = 5000
    lam0, lam1 = np.array([1.0, 3.0]), np.array([2.0, 2.0])
    k = np.arange(40)
    grid = np.stack(np.meshgrid(k, k, indexing="ij"), axis=-1).reshape(-1, 2)
    llr = ideal_observer(
        grid,
        signal=np.broadcast_to(lam1, grid.shape),
        background=np.broadcast_to(lam0, grid.shape),
    )
    p0 = poisson.pmf(grid, lam0).prod(axis=1)
    p1 = poisson.pmf(grid, lam1).prod(axis=1)
    values, index = np.unique(np.round(llr, 9), return_inverse=True)
    law0 = np.bincount(index, weights=p0, minlength=len(values))
    law1 = np.bincount(index, weights=p1, minlength=len(values))
    exact = np.sum(law1 * (np.cumsum(law0) - law0 / 2))
    draws = rng(8)
    means = {"signal": np.broadcast_to(lam1, (n, 2)), "background": np.broadcast_to(lam0, (n, 2))}
    s0 = ideal_observer(draws.poisson(lam0, (n, 2)), **means)
    s1 = ideal_observer(draws.poisson(lam1, (n, 2)), **means)
    low, high = bootstrap_auc(positives=s1, negatives=s0)
    assert low <= exact <= high


def test_logistic_regression_recovers_a_known_model():
    n = 20000
    draws = rng(9)
    x = draws.normal(size=(n, 2))
    truth = np.array([0.5, 2.0, -1.0])
    logit = truth[0] + x @ truth[1:]
    y = draws.random(n) < 1 / (1 + np.exp(-logit))
    model = fit_logistic(x, y, penalty=1e-6)
    # back to the raw features' scale, and the standard errors from the Fisher information
    beta = model.coefficients[1:] / model.scale
    intercept = model.coefficients[0] - np.sum(beta * model.center)
    p = 1 / (1 + np.exp(-logit))
    design = np.column_stack([np.ones(n), x])
    se = np.sqrt(np.diag(np.linalg.inv((design * (p * (1 - p))[:, None]).T @ design)))
    np.testing.assert_array_less(np.abs(np.r_[intercept, beta] - truth), 4 * se)


def point_dataset(points, *, realisations=2):
    """A store's labels and swept coordinates, enough for `pair_points`."""
    names = list(points[0])
    coords = {
        name.replace(".", "_"): (
            "sample",
            np.repeat([p[name] for p in points], realisations),
            {"parameter": name},
        )
        for name in names
    }
    present = np.repeat([p.get("target.shape", "sphere") != "none" for p in points], realisations)
    ds = xr.Dataset({"target_present": ("sample", present)}, coords=coords)
    ds.attrs.update(points=len(points), realisations=realisations)
    return ds


def test_points_pair_with_the_target_free_twin_of_their_scene():
    grid = [
        {"target.depth": d, "water.preset": w, "target.shape": s}
        for d in (3.0, 6.0)
        for w in ("clear_ocean", "coastal")
        for s in ("sphere", "none")
    ]
    pairs, unpaired = pair_points(point_dataset(grid))
    assert pairs == [(0, 1), (2, 3), (4, 5), (6, 7)] and unpaired == []
    # one target-free point per water serves every depth (the target's depth means nothing
    # without a target); a water with no target-free point is left unpaired
    shared = [
        {"target.depth": 3.0, "water.preset": "coastal", "target.shape": "none"},
        {"target.depth": 3.0, "water.preset": "coastal", "target.shape": "sphere"},
        {"target.depth": 6.0, "water.preset": "coastal", "target.shape": "sphere"},
        {"target.depth": 6.0, "water.preset": "clear_ocean", "target.shape": "sphere"},
    ]
    assert pair_points(point_dataset(shared)) == ([(1, 0), (2, 0)], [3])


@pytest.mark.parametrize(
    ("shapes", "message"),
    [(["sphere", "disk"], "no negatives"), (["none", "none"], "nothing to detect")],
    ids=["no-negatives", "no-target"],
)
def test_pairing_refuses_a_sweep_without_both_classes(shapes, message):
    points = [{"target.depth": 3.0 + i, "target.shape": s} for i, s in enumerate(shapes)]
    with pytest.raises(InputError, match=message):
        pair_points(point_dataset(points))


SWEEP = (
    TINY_SCENE.replace("gates: [[2.0, 6.0]]", "gates: [[1.0, 6.0]]").replace(
        "white_plane_photons: 100", "white_plane_photons: 10"
    )
    + """\
store: {{expected: true}}
sweep:
  parameters:
    target.depth: {{values: [1.5, 5.0]}}
    water.preset: {{values: [clear_ocean, coastal]}}
    target.shape: {{values: [sphere, none]}}
"""
)
"""Tiny samples, a sphere at two depths in two waters, each with its target-free twin."""


@pytest.fixture(scope="module")
def detection(tmp_path_factory, session_cluster):
    folder = tmp_path_factory.mktemp("detect")
    sweep = folder / "sweep.yaml"
    sweep.write_text(
        SWEEP.format(name="small", seed=5, realisations=120, output=folder / "small.zarr")
    )
    with on_cluster(session_cluster):
        assert main(["run", str(sweep), "--workers", "1"]) == 0
    assert main(["detect", str(folder / "small.zarr")]) == 0
    return folder, xr.open_zarr(folder / "small.detect.zarr").load()


def test_detection_dataset_layout(detection):
    _, det = detection
    assert det["detector"].values.tolist() == list(DETECTORS)
    assert det["point"].values.tolist() == [0, 2, 4, 6]
    assert det["negative_point"].values.tolist() == [1, 3, 5, 7]
    assert det["gate"].values.tolist() == [1]  # numbered from 1, as the samples' (issue #27)
    assert det["gate_auc"].dims == ("point", "gate")
    for name, variable in det.variables.items():
        assert "long_name" in variable.attrs, name
        if variable.dtype.kind in "biuf":
            assert variable.attrs["units"] == "1" or name.startswith(("gate", "target_")), name
    assert det.attrs["detector_ideal_observer"] == DETECTORS["ideal_observer"]
    # the trained detector is evaluated on the held-out (odd) realisations only
    held = det["held_out"].values.astype(bool)
    assert held.sum() == 60 and held[1] and not held[0]
    logistic = det["score_positive"].sel(detector="logistic_regression").values
    assert np.isnan(logistic[:, ~held]).all() and np.isfinite(logistic[:, held]).all()
    assert det["evaluated"].values.tolist() == [[120, 60, 120, 60]] * 4
    # 120 negatives measure Pfa = 0.1, not 0.01; the trained detector's 60 measure 0.1 too
    assert det["pd_available"].sel(pfa=0.1).values.all()
    assert not det["pd_available"].sel(pfa=0.01).values.any()
    assert np.isnan(det["pd"].sel(pfa=0.01).values).all()
    # each ROC runs from (0, 0) to (1, 1) and its area is the AUC
    for p in range(4):
        for d in range(4):
            pfa, pd = (det[v].values[p, d] for v in ("roc_pfa", "roc_pd"))
            pfa, pd = pfa[~np.isnan(pfa)], pd[~np.isnan(pd)]
            assert (pfa[0], pd[0], pfa[-1], pd[-1]) == (0, 0, 1, 1)
            assert np.trapezoid(pd, pfa) == pytest.approx(float(det["auc"][p, d]))


def test_a_cf_checker_passes_the_detection_export(detection, tmp_path):
    # issue #27: pfa, a coordinate, had a _FillValue (NaN), which CF forbids on one
    folder, _ = detection
    exported = open_dataset(str(folder / "small.detect.zarr"))
    assert cf_failures(exported, tmp_path / "detect.nc") == []


def test_scores_compare_the_samples_of_one_realisation(detection):
    """Each score pits the positive and the negative sample of realisation r against the
    expected images of realisation r at both points: the same sea, never another's."""
    folder, det = detection
    ds = xr.open_zarr(folder / "small.zarr")
    r = ds.attrs["realisations"]
    ideal = det.sel(detector="ideal_observer")
    for i, (p, q) in enumerate(
        zip(det["point"].values, det["negative_point"].values, strict=True)
    ):
        signal = ds["expected"][p * r : (p + 1) * r].values
        background = ds["expected"][q * r : (q + 1) * r].values
        for name, point in (("score_positive", p), ("score_negative", q)):
            image = ds["image"][point * r : (point + 1) * r].values
            np.testing.assert_allclose(
                ideal[name].values[i],
                ideal_observer(image, signal=signal, background=background),
                rtol=1e-12,
            )


def test_the_sea_marginal_observer_scores_held_out_images_over_the_training_seas(detection):
    """Each held-out image is scored over the expected images of the training realisations
    (the sea's law), never its own sea's; its Monte Carlo error comes with it."""
    folder, det = detection
    ds = xr.open_zarr(folder / "small.zarr")
    r = ds.attrs["realisations"]
    held = det["held_out"].values.astype(bool)
    marginal = det.sel(detector="sea_marginal_observer")
    for i, (p, q) in enumerate(
        zip(det["point"].values, det["negative_point"].values, strict=True)
    ):
        seas = {
            "signal": ds["expected"][p * r : (p + 1) * r].values[~held],
            "background": ds["expected"][q * r : (q + 1) * r].values[~held],
        }
        for name, point in (("score_positive", p), ("score_negative", q)):
            image = ds["image"][point * r : (point + 1) * r].values
            scores = marginal[name].values[i]
            assert np.isnan(scores[~held]).all()
            np.testing.assert_allclose(
                scores[held], sea_marginal_observer(image[held], **seas), rtol=1e-12
            )
    assert det["seas"].values.tolist() == [60] * 4
    assert (det["sea_auc_se"] > 0).all() and (det["sea_auc_se"] < 0.05).all()
    assert ((det["effective_seas"] >= 1) & (det["effective_seas"] <= 60)).all()
    assert (np.abs(det["auc_half_seas"] - marginal["auc"]) < 0.1).all()


def test_ideal_observer_bounds_the_other_detectors(detection):
    _, det = detection
    ideal = det.sel(detector="ideal_observer")
    for other in ("sea_marginal_observer", "matched_filter", "logistic_regression"):
        assert (ideal["auc_high"] >= det["auc"].sel(detector=other)).all(), other
    assert (det["auc"] > 0.5).all()


def test_auc_falls_with_depth_and_turbidity(detection):
    _, det = detection
    # points: (1.5 m, clear), (1.5 m, coastal), (5 m, clear), (5 m, coastal)
    ideal = det.sel(detector="ideal_observer")
    for shallow, deep in ((0, 2), (1, 3)):
        assert float(ideal["auc_low"][shallow]) > float(ideal["auc_high"][deep])
    # clear > coastal at 5 m, one-sided at 95 % on the difference (each AUC's standard error
    # from its 95 % bootstrap interval, 2 x 1.96 wide): since the target is seen through the
    # sub-grid slopes (issue #36) the clear water's sphere spreads as the coastal one already
    # did, and the gap (0.07) no longer clears both intervals at 120 realisations
    error = np.hypot(*((ideal["auc_high"][i] - ideal["auc_low"][i]) / 3.92 for i in (2, 3)))
    assert float(ideal["auc"][2] - ideal["auc"][3]) > 1.645 * float(error)
    for name in ("ideal_observer", "matched_filter"):
        area = det["auc"].sel(detector=name).values
        assert area[0] > area[2] and area[1] > area[3], name
        assert area[0] > area[1] and area[2] > area[3], name


def test_detection_is_deterministic_and_plots(detection, tmp_path, capsys):
    folder, det = detection
    again = tmp_path / "again.detect.zarr"
    assert main(["detect", str(folder / "small.zarr"), "--workers", "0"]) == 2
    assert "--workers must be at least 1" in capsys.readouterr().err
    # on processes (an embedded cluster) this time, the fixture's on threads
    argv = ["detect", str(folder / "small.zarr"), "--output", str(again), "--workers", "1"]
    assert main(argv) == 0
    # its set-up phases and the points scored of the total (a log's lines: no terminal)
    err = capsys.readouterr().err.splitlines()
    assert re.match(r"starting the local cluster \(1 worker\)\.\.\. [\d.]+ s$", err[0])
    assert re.match(r"scoring the first point \(reading the expected .*\.\.\. [\d.]+ s$", err[1])
    assert re.match(r"100%\|#+\| 4/4 \[\d\d:\d\d<00:00, +[\d.]+(s/)? points(/s)?\]$", err[-2])
    assert re.match(r"writing the detection dataset\.\.\. [\d.]+ s$", err[-1])
    # an earlier detection dataset there is replaced (its nested chunk keys' folders went
    # with it: they were left behind, and the new dataset could not be moved in)
    assert main(["detect", str(folder / "small.zarr"), "--output", str(again)]) == 0
    other = xr.open_zarr(again).load()
    for name in det.variables:
        assert same_values(det[name].values, other[name].values), name
    picture = tmp_path / "det.png"
    assert main(["plot", str(again), "--output", str(picture)]) == 0
    assert picture.stat().st_size > 10000


def test_expected_images_missing_from_the_store_are_rendered_again(detection, tmp_path):
    folder, det = detection
    bare = tmp_path / "bare.zarr"
    copy = xr.open_zarr(folder / "small.zarr").drop_vars("expected")
    for variable in copy.variables.values():
        variable.encoding = {}  # written afresh: dask's chunks, not the shards
    with consolidated_v3():
        copy.to_zarr(bare, zarr_format=3, consolidated=True)
    # what a store written without them records: the checksums of the arrays it holds
    group = zarr.open_group(bare, mode="r+")
    arrays = [group[name][:] for name in rendered_order() if name in group]
    group["checksum_bound"][:] = [
        sample_checksum([a[s] for a in arrays], "checksum_bound", sample_identity(copy.attrs, s))
        for s in range(copy.sizes["sample"])
    ]
    assert main(["detect", str(bare)]) == 0
    again = xr.open_zarr(tmp_path / "bare.detect.zarr").load()
    assert again.attrs["expected_images"] == "rendered again"
    assert det.attrs["expected_images"] == "read from the store"
    for name in ("score_positive", "score_negative", "auc", "auc_low", "auc_high", "pd"):
        assert det[name].values.tobytes() == again[name].values.tobytes(), name


def copied(detection, tmp_path):
    """A copy of the detection fixture's store, to damage, and its samples per shard."""
    folder, _ = detection
    copy = tmp_path / "small.zarr"
    shutil.copytree(folder / "small.zarr", copy)
    return copy, int(zarr.open_group(copy, mode="r")["completed"].chunks[0])


def flip_byte(path):
    data = bytearray(path.read_bytes())
    data[len(data) // 3] ^= 0x01  # inside a chunk: the shard's index is at its end
    path.write_bytes(bytes(data))


def swap_files(copy, first, second):
    """Swap two shards' files in every per-sample array, checksums and flags included."""
    for folder in copy.iterdir():
        files = {p.name.split(".")[1]: p for p in folder.glob("c.*")} if folder.is_dir() else {}
        if str(first) in files and str(second) in files:
            a, b = files[str(first)], files[str(second)]
            data = a.read_bytes()
            a.write_bytes(b.read_bytes())
            b.write_bytes(data)


DETECT_ATTACKS = {
    # shard 1 damaged (point 1, a negative, with the default layout)
    "shard-lost": (lambda c: next((c / "image").glob("c.1.*")).unlink(), "do not match"),
    "byte-flipped": (lambda c: flip_byte(next((c / "image").glob("c.1.*"))), "cannot be read"),
    "shard-cut-short": (
        lambda c: next((c / "image").glob("c.1.*")).write_bytes(b"\x00" * 100),
        "cannot be read",
    ),
    "shards-swapped": (lambda c: swap_files(c, 1, 3), "do not match"),
}


@pytest.mark.parametrize("attack", DETECT_ATTACKS)
def test_detect_refuses_samples_that_fail_their_checks(detection, tmp_path, capsys, attack):
    # issue #37 items 1 and 2: detect read around the samples' checks: an image shard lost
    # took an AUC from 1.000 to 0.5 with exit 0, a flipped byte ended in a traceback naming
    # no sample, and shards swapped whole (checksums too) passed every check
    copy, size = copied(detection, tmp_path)
    damage, reason = DETECT_ATTACKS[attack]
    damage(copy)
    assert main(["detect", str(copy)]) == 1
    err = capsys.readouterr().err
    found = re.search(
        r"error: sample (\d+): its (image chunk cannot be read|chunks do not match)", err
    )
    assert found and reason in found[0], err
    shards = (1, 3) if attack == "shards-swapped" else (1,)
    assert int(found[1]) // size in shards
    assert "--resume --verify" in err and "Traceback" not in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["small.zarr"]  # no dataset, no lock


def test_detect_names_a_file_of_flags_that_cannot_be_read(detection, tmp_path, capsys):
    # issue #37 item 6: a zero-length completed file ended in a traceback naming nothing
    copy, _ = copied(detection, tmp_path)
    (copy / "completed" / "c.1").write_bytes(b"")
    assert main(["detect", str(copy)]) == 1
    err = capsys.readouterr().err
    assert f"{copy}/completed/c.1: cannot be read" in err and "--resume --verify" in err
    assert "Traceback" not in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["small.zarr"]


def test_detect_compares_the_labels_with_the_sweeps(detection, tmp_path, capsys):
    # issue #37 item 1: as info --verify, stats and the training reader do
    copy, _ = copied(detection, tmp_path)
    depth = zarr.open_array(copy / "target_depth", mode="r+")
    depth[0] = 9.0
    assert main(["detect", str(copy)]) == 1
    err = capsys.readouterr().err
    assert "its target_depth differ from what its sweep gives" in err and "Traceback" not in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["small.zarr"]


def test_detect_holds_the_stores_lock(detection, tmp_path, capsys):
    # issue #37 item 16: three detects at once on one store left tracebacks ("Directory not
    # empty") and .partial-* folders; one holding the store's lock refuses the others
    copy, _ = copied(detection, tmp_path)
    with Store.at(str(copy)).lock():  # another detect, or a run, holds it
        assert main(["detect", str(copy)]) == 2
        err = capsys.readouterr().err
        assert f"{copy} is locked by another run" in err and "Traceback" not in err
        assert sorted(p.name for p in tmp_path.iterdir()) == ["small.zarr", "small.zarr.lock"]
    assert main(["detect", str(copy)]) == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["small.detect.zarr", "small.zarr"]


def test_detect_refuses_to_overwrite_what_is_not_a_detection_dataset(detection, capsys):
    folder, _ = detection
    argv = ["detect", str(folder / "small.zarr"), "--output", str(folder / "small.stats.zarr")]
    assert main(argv) == 2
    assert "statistics" in capsys.readouterr().err
    precious = folder / "precious"
    precious.mkdir()
    (precious / "notes.txt").write_text("keep")
    assert main(["detect", str(folder / "small.zarr"), "--output", str(precious)]) == 2
    assert "not an oceanlidar detection store" in capsys.readouterr().err
    assert (precious / "notes.txt").read_text() == "keep"


def test_detect_refuses_a_target_free_sweep(tmp_path, capsys, shared_cluster):
    sweep = tmp_path / "sweep.yaml"
    text = TINY_SCENE.format(name="empty", seed=1, realisations=8, output=tmp_path / "e.zarr")
    sweep.write_text(text + "sweep:\n  parameters:\n    target.shape: {values: [none]}\n")
    assert main(["run", str(sweep), "--workers", "1"]) == 0
    capsys.readouterr()
    assert main(["detect", str(tmp_path / "e.zarr")]) == 2
    assert "nothing to detect" in capsys.readouterr().err
    assert not (tmp_path / "e.detect.zarr").exists()


@pytest.mark.parametrize(
    ("change", "realisations", "message"),
    [
        ("white_plane_photons: 10", 8, "fewer than 8; complete the run"),
        ("white_plane_photons: 10}}\n  noise: {{gain: 2.0", 8, "not photoelectrons"),
        ("white_plane_photons: 10", 4, "needs at least 8"),
    ],
    ids=["not-written", "gain", "too-few-realisations"],
)
def test_detect_refuses_stores_it_cannot_evaluate(tmp_path, capsys, change, realisations, message):
    text = SWEEP.replace("white_plane_photons: 10", change).format(
        name="t", seed=1, realisations=realisations, output="t.zarr"
    )
    url = str(tmp_path / "t.zarr")
    create_store(parse_sweep(text), Store(url))  # the template: no sample written yet
    assert main(["detect", url]) == 2
    err = capsys.readouterr().err
    assert message in err
    # refused before anything is scored (issue #37 item 16: no task fails, so none leaves
    # a "Task exception was never retrieved")
    assert "scoring" not in err and "Traceback" not in err and "Task exception" not in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["t.zarr"]


def test_the_detection_plot_names_each_combination_and_no_category_alone(
    detection, tmp_path, monkeypatch
):
    # issue #37 item 19: lines of AUC and Pd against a parameter, one per combination of
    # the others, were drawn alike with nothing to say which is which; a parameter that
    # takes one value got a panel of its own
    _, det = detection
    det = det.assign(
        target_radius=("point", np.full(4, 0.3), {"parameter": "target.radius", "units": "m"})
    )
    drawn = []
    original = service.plots.new_figure
    monkeypatch.setattr(
        service.plots, "new_figure", lambda **k: drawn.append(original(**k)) or drawn[-1]
    )
    service.charts.plot_detection(det, str(tmp_path / "d.png"))
    auc, pd = drawn[0].axes[4:8], drawn[0].axes[8:12]  # one ROC row of 4, then AUC, Pd
    assert [ax.get_xlabel() for ax in auc[:2]] == ["target_depth (m)", "water_preset"]
    assert not any(ax.axison for ax in (*auc[2:], *pd[2:]))  # no radius column
    assert [t.get_text() for t in pd[0].get_legend().get_texts()] == [
        "preset=clear_ocean",
        "preset=coastal",
    ]
    assert [t.get_text() for t in pd[1].get_legend().get_texts()] == ["depth=1.5", "depth=5"]
    # each AUC line: one detector's points of one water, in its marker
    markers = {line.get_marker() for line in auc[0].lines if len(line.get_xdata()) == 2}
    assert markers == set(service.charts.MARKERS[:2])


def test_a_detector_with_no_pair_evaluated_has_nan_metrics():
    # The sea-marginal observer's scores are NaN at every held-out realisation when each of
    # its seas gives an image zero likelihood (a Monte Carlo store at few photons: sparse
    # expected images); `detect` stopped on an IndexError in the bootstrap. Now the detector
    # is not evaluated: 0 pairs, every metric NaN.
    nan = np.full(12, np.nan)
    metrics = score_metrics(positives=np.arange(12.0), negatives=nan, pfa=(0.01, 0.1))
    assert metrics["evaluated"] == 0
    assert np.isnan([metrics["auc"], metrics["auc_low"], metrics["auc_high"]]).all()
    assert metrics["pd"].shape == (2,) and np.isnan(metrics["pd"]).all()
    # one pair left: evaluated on it
    one = nan.copy()
    one[3] = 1.0
    assert score_metrics(positives=np.arange(12.0), negatives=one, pfa=(0.1,))["evaluated"] == 1
