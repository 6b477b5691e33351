"""Bayes filter: RTAB-Map likelihood normalisation, prediction model, posterior on planted evidence."""

from __future__ import annotations

import numpy as np
import pytest

from fleetslam.errors import SlamError
from fleetslam.slam.bayes_filter import VIRTUAL_PLACE, BayesFilter, adjust_likelihood
from fleetslam.slam.loop_config import DEFAULT_PREDICTION_LC


def chain(n: int):
    """Neighbours of a chain of locations 1..n linked by odometry."""

    def neighbors(i: int) -> list[int]:
        return [j for j in (i - 1, i + 1) if 1 <= j <= n]

    return neighbors


def test_adjust_likelihood_follows_rtabmap_normalisation() -> None:
    raw = {1: 0.0, 2: 0.1, 3: 0.0, 4: 0.9, 5: 0.05}
    values = np.array(list(raw.values()))
    mean, std = values.mean(), values.std()
    adjusted = adjust_likelihood(raw)
    assert adjusted[4] == pytest.approx((0.9 - mean) / std + 1.0)
    assert adjusted[1] == adjusted[2] == adjusted[3] == adjusted[5] == 1.0
    assert adjusted[VIRTUAL_PLACE] == pytest.approx(mean / std + 1.0)
    flat = adjust_likelihood({1: 0.0, 2: 0.0})
    assert flat == {1: 1.0, 2: 1.0, VIRTUAL_PLACE: 2.0}


def test_prediction_conserves_probability_and_favours_neighbours() -> None:
    bayes = BayesFilter()
    ids = [VIRTUAL_PLACE, *range(1, 31)]
    previous = dict.fromkeys(ids, 0.0)
    previous[15] = 1.0
    prior = bayes.predict(ids, previous, chain(30))
    assert sum(prior.values()) == pytest.approx(1.0)
    total = DEFAULT_PREDICTION_LC[0] + DEFAULT_PREDICTION_LC[1] + 2 * sum(DEFAULT_PREDICTION_LC[2:])
    assert prior[15] == pytest.approx(DEFAULT_PREDICTION_LC[1] / total)
    assert prior[14] == pytest.approx(prior[16]) == pytest.approx(DEFAULT_PREDICTION_LC[2] / total)
    assert prior[VIRTUAL_PLACE] == pytest.approx(DEFAULT_PREDICTION_LC[0] / total)
    assert prior[15] > prior[14] > prior[13] > prior[12]
    # From the virtual place: 0.9 stays, the rest is uniform over the locations.
    previous = dict.fromkeys(ids, 0.0)
    previous[VIRTUAL_PLACE] = 1.0
    prior = bayes.predict(ids, previous, chain(30))
    assert prior[VIRTUAL_PLACE] == pytest.approx(0.9)
    assert prior[7] == pytest.approx(0.1 / 30)
    # An isolated location: the column sums below 1, the rest is spread over the other locations.
    prior = bayes.predict([VIRTUAL_PLACE, 1, 2, 3], {1: 1.0}, lambda i: [])
    assert sum(prior.values()) == pytest.approx(1.0)
    assert prior[2] == pytest.approx(prior[3]) == pytest.approx((1.0 - 0.1 - 0.36) / 2)


def test_prediction_asks_for_each_locations_links_once_and_walks_only_the_hypotheses() -> None:
    """Every location's walk reaches its neighbours' links again: one prediction looks each up once (the memory's
    ``neighbors`` sorts a location's links per call). Links to locations that are no hypothesis (in long-term
    memory) are not walked through: 10 and 20 link 1..9 and 11..19 only through 10 and 20, which are left out."""
    calls: dict[int, int] = {}
    links = chain(30)

    def neighbors(i: int) -> list[int]:
        calls[i] = calls.get(i, 0) + 1
        return links(i)

    ids = [VIRTUAL_PLACE, *[i for i in range(1, 31) if i not in (10, 20)]]
    previous = dict.fromkeys(ids, 1.0 / len(ids))
    prior = BayesFilter().predict(ids, previous, neighbors)
    assert calls and max(calls.values()) == 1
    assert 10 not in calls and 20 not in calls
    assert sum(prior.values()) == pytest.approx(1.0)
    # 9 has one neighbour among the hypotheses (8), as 1 does (2): the same prior, less than 5's, which has two.
    assert prior[9] == pytest.approx(prior[1]) and prior[9] < prior[5]


def test_posterior_stays_on_virtual_place_without_evidence_and_follows_a_revisit() -> None:
    bayes = BayesFilter()
    neighbors = chain(40)
    rng = np.random.default_rng(0)
    # The working memory grows by one location per keyframe, as in the detector.
    for n in range(1, 41):
        raw = {i: float(rng.uniform(0.0, 0.01)) for i in range(1, n + 1)}
        posterior = bayes.compute_posterior(adjust_likelihood(raw), neighbors)
        assert sum(posterior.values()) == pytest.approx(1.0)
        if n > 3:
            assert 1.0 - posterior[VIRTUAL_PLACE] < 0.11
    for revisited in (20, 21, 22):
        raw = {i: float(rng.uniform(0.0, 0.01)) for i in range(1, 41)}
        raw[revisited] = 0.5
        posterior = bayes.compute_posterior(adjust_likelihood(raw), neighbors)
    best = max((i for i in posterior if i != VIRTUAL_PLACE), key=posterior.__getitem__)
    assert best == 22
    assert 1.0 - posterior[VIRTUAL_PLACE] > 0.11


def test_new_hypotheses_start_at_zero_and_removed_ones_are_dropped() -> None:
    bayes = BayesFilter()
    bayes.compute_posterior({VIRTUAL_PLACE: 1.0, 1: 1.0, 2: 1.0}, chain(2))
    posterior = bayes.compute_posterior({VIRTUAL_PLACE: 1.0, 2: 1.0, 3: 5.0}, chain(3))
    assert set(posterior) == {VIRTUAL_PLACE, 2, 3}
    # 3 was unknown: its prior comes only from the prediction (from 2 and the virtual place).
    assert posterior[3] > 0
    with pytest.raises(SlamError, match="virtual place"):
        bayes.compute_posterior({1: 1.0}, chain(1))
    with pytest.raises(SlamError, match="prediction_lc"):
        BayesFilter(prediction_lc=[0.1])
