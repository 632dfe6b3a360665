"""The detector network itself (`workers.detectors.cnn`) on small synthetic Poisson pictures.

Each task here is built so that a detector lacking one ability stays at chance: the place
of the target (a translation-invariant score cannot tell a blob at the centre from the same
blob elsewhere), the sweep point (the same brightness means a target at one point and none
at another). Seconds each: 12 × 12 pictures, a few hundred samples, a few epochs.
"""

from dataclasses import replace

import numpy as np
import pytest
import torch

from workers.detectors.cnn import CnnSettings, DetectorNet, score, train_detector
from workers.detectors.detection import auc

SIZE = (24, 24)
BACKGROUND = 4.0
"""Mean counts of a target-free pixel [photoelectrons]."""
BLOB = 6.0
"""Counts a blob adds to each of its 2 × 2 pixels in both gates [photoelectrons]."""
QUICK = CnnSettings(width=8, epochs=12, learning_rate=3e-3, batch_size=32)


def place_samples(n, *, seed):
    """`n` positives (the blob at the centre) and `n` negatives (the same blob elsewhere).

    Pictures (2n, 1 frame, 2 gates, 24, 24) of Poisson counts. The blob is 2 × 2 pixels;
    the negatives' lie an even number of pixels (the pooling's period) from the centre's,
    and at least 7 pixels from every edge, beyond what the old network's three convolutions
    and pooling see (a reach of 5 pixels): a translation-invariant score sees both classes
    alike, only the place tells them apart.
    """
    rng = np.random.default_rng(seed)
    mean = np.full((2 * n, 1, 2, *SIZE), BACKGROUND)
    mean[:n, ..., 11:13, 11:13] += BLOB
    corners = [(y, x) for y in range(7, 17, 2) for x in range(7, 17, 2) if (y, x) != (11, 11)]
    for i, pick in enumerate(rng.integers(0, len(corners), size=n), start=n):
        y, x = corners[pick]
        mean[i, ..., y : y + 2, x : x + 2] += BLOB
    labels = np.repeat([1.0, 0.0], n)
    return rng.poisson(mean).astype(np.uint8), labels


def point_samples(n, *, seed):
    """A uniform brightness that means a target at one point and none at the other.

    Point A (condition -1): 4 photoelectrons a pixel without the target, 5 with; point B
    (condition +1): 5 without, 6 with. `n` of each class at each point, (4n, ...) pictures,
    labels and conditions (4n, 1).
    """
    rng = np.random.default_rng(seed)
    level = np.repeat([5.0, 4.0, 6.0, 5.0], n)  # A with, A without, B with, B without
    mean = level[:, None, None, None, None] * np.ones((1, 1, 2, *SIZE))
    labels = np.tile(np.repeat([1.0, 0.0], n), 2)
    conditions = np.repeat([-1.0, 1.0], 2 * n)[:, None]
    return rng.poisson(mean).astype(np.uint8), labels, conditions.astype(np.float32)


def batches(images, labels, conditions=None, *, size=32, seed=0):
    """Shuffled (by `seed`) lists of batch dicts, the same every epoch."""
    order = np.random.default_rng(seed).permutation(len(labels))
    out = []
    for start in range(0, len(order), size):
        pick = order[start : start + size]
        batch = {"image": images[pick], "target_present": labels[pick]}
        if conditions is not None:
            batch["conditions"] = conditions[pick]
        out.append(batch)
    return out


def in_order(images, conditions=None, *, size=64):
    """Unshuffled batch dicts for `score`."""
    return [
        {"image": images[s : s + size]}
        | ({} if conditions is None else {"conditions": conditions[s : s + size]})
        for s in range(0, len(images), size)
    ]


def cross_entropy(scores, labels):
    """Per-sample binary cross-entropy [nats] of log-odds `scores` against `labels`."""
    return np.where(labels == 1, np.logaddexp(0, -scores), np.logaddexp(0, scores))


@pytest.fixture(scope="module")
def place():
    """Training (300 a class) and held-out (200 a class) samples of the place task."""
    return place_samples(300, seed=1), place_samples(200, seed=2)


@pytest.fixture(scope="module")
def place_scores(place):
    (images, labels), (held, held_labels) = place
    model = train_detector(
        batches(images, labels), channels=2, size=SIZE, settings=QUICK, device="cpu"
    )
    return score(model, in_order(held)), held_labels


def test_a_target_at_a_known_place_is_told_from_the_same_light_elsewhere(place_scores):
    # The blob is 6 photoelectrons over 4 in 18 pixels (both gates): known in place, a
    # matched filter's statistic separates the classes by about 6 standard deviations
    # (an AUC of 1 to three decimals). A score blind to place (global max and mean
    # pooling: the old network) stays near 0.5: 0.5 ± 0.036 at 400 pairs (Mann–Whitney's
    # standard error under H0).
    scores, labels = place_scores
    assert auc(positives=scores[labels == 1], negatives=scores[labels == 0]) > 0.98


def test_held_out_cross_entropy_beats_a_guess_and_shuffled_labels_do_not(place, place_scores):
    # A score that knows nothing of the label has a mean cross-entropy at least ln 2 (Gibbs'
    # inequality, balanced classes); its mean over the 400 held-out samples errs by its
    # standard deviation / sqrt(400). Trained on the labels, the network is below ln 2 by
    # far more than 4 such errors; trained on shuffled labels, it is not below.
    scores, labels = place_scores
    loss = cross_entropy(scores, labels)
    margin = 4 * loss.std() / np.sqrt(loss.size)
    assert loss.mean() < np.log(2) - margin
    assert loss.mean() < 0.2
    (images, train_labels), (held, held_labels) = place
    shuffled = np.random.default_rng(3).permutation(train_labels)
    model = train_detector(
        batches(images, shuffled), channels=2, size=SIZE, settings=QUICK, device="cpu"
    )
    blind = cross_entropy(score(model, in_order(held)), held_labels)
    assert blind.mean() > np.log(2) - 4 * blind.std() / np.sqrt(blind.size)


def test_the_point_tells_what_a_brightness_means():
    # Five photoelectrons a pixel is a target at point A and none at point B. Told the
    # point, a network reads each point's level (288 pixels: 5 against 4 is 8.5 standard
    # deviations of the mean count apart, an AUC of 1); blind to it, the pooled AUC over
    # both points is at most 0.875 (a quarter of the pairs, A's positives against B's
    # negatives, have the same law: 0.5 there), ± 0.010 here (that quarter's Mann–Whitney
    # standard error at 100 against 100, over 4): 0.95 is 7 such errors above.
    images, labels, conditions = point_samples(150, seed=4)
    held, held_labels, held_conditions = point_samples(100, seed=5)
    told = train_detector(
        batches(images, labels, conditions),
        channels=2,
        size=SIZE,
        conditions=1,
        settings=QUICK,
        device="cpu",
    )
    s = score(told, in_order(held, held_conditions))
    assert auc(positives=s[held_labels == 1], negatives=s[held_labels == 0]) > 0.95


def test_a_network_with_conditions_refuses_a_batch_without():
    model = DetectorNet(2, size=SIZE, conditions=3, width=4)
    with pytest.raises(ValueError, match="conditions"):
        model(torch.zeros((1, 1, 2, *SIZE)))


def test_the_same_seed_gives_the_same_bytes_and_another_seed_another_network(place):
    (images, labels), (held, _) = place
    small = CnnSettings(width=4, epochs=2, batch_size=32)

    def trained(seed):
        model = train_detector(
            batches(images[::4], labels[::4]),
            channels=2,
            size=SIZE,
            settings=replace(small, seed=seed),
            device="cpu",
        )
        return score(model, in_order(held)).tobytes()

    first = trained(0)
    assert first == trained(0)
    assert first != trained(1)


def test_each_epochs_mean_training_loss_is_reported(place):
    (images, labels), _ = place
    losses = []
    train_detector(
        batches(images, labels),
        channels=2,
        size=SIZE,
        settings=QUICK,
        device="cpu",
        on_epoch=lambda epoch, loss: losses.append((epoch, loss)),
    )
    assert [e for e, _ in losses] == list(range(QUICK.epochs))
    # cross-entropies [nats] that fall as the network learns the place
    assert all(0 < loss < 1 for _, loss in losses)
    assert losses[-1][1] < 0.5 * losses[0][1]
