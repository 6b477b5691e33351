"""Discrete Bayes filter over loop-closure hypotheses (RTAB-Map ``BayesFilter``).

State: one hypothesis per location of the working memory ("the current image closes a loop with location
i") plus the virtual place ``VIRTUAL_PLACE`` ("the current image is a new place"). Each keyframe:

1. prediction ``prior = P · posterior``. Column j of the transition matrix P (from hypothesis j):
   - j a location: ``prediction_lc[0]`` to the virtual place, ``prediction_lc[1]`` to j itself,
     ``prediction_lc[1 + d]`` to each location at graph depth d from j (links in the working memory).
     If these sum below 1 the rest is spread uniformly over the other locations; above 1 the column is
     divided by its sum (RTAB-Map normalises the same way).
   - j the virtual place: ``virtual_place_prior`` to itself, the rest uniformly to every location.
2. update ``posterior = likelihood ⊙ prior``, normalised.

Hypotheses that appear (new or retrieved locations) start at 0, except on the first update where the
posterior starts uniform; hypotheses that disappear (transferred to LTM) are dropped.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Iterable, Mapping, Sequence

import numpy as np

from fleetslam.errors import SlamError
from fleetslam.slam.loop_config import DEFAULT_PREDICTION_LC

VIRTUAL_PLACE = -1
"""Id of the "new place" hypothesis."""

NeighborFn = Callable[[int], Iterable[int]]


def adjust_likelihood(raw: Mapping[int, float]) -> dict[int, float]:
    """RTAB-Map's likelihood normalisation of raw similarities (virtual place excluded from ``raw``).

    With μ, σ the mean and standard deviation of the raw scores: ``s' = (s - μ)/σ + 1`` if ``s ≥ μ + σ``
    else 1, and the virtual place gets ``μ/σ + 1`` (2 when σ is 0, i.e. nothing stands out).
    """
    out: dict[int, float] = {}
    if not raw:
        out[VIRTUAL_PLACE] = 1.0
        return out
    values = np.fromiter(raw.values(), dtype=np.float64, count=len(raw))
    mean = float(values.mean())
    std = float(values.std())
    for location, score in raw.items():
        out[location] = (score - mean) / std + 1.0 if std > 0 and score >= mean + std else 1.0
    out[VIRTUAL_PLACE] = mean / std + 1.0 if std > 0 else 2.0
    return out


class BayesFilter:
    """Recursive Bayes estimation of the loop-closure posterior."""

    def __init__(
        self,
        prediction_lc: Sequence[float] = DEFAULT_PREDICTION_LC,
        virtual_place_prior: float = 0.9,
    ) -> None:
        if len(prediction_lc) < 2:
            raise SlamError(
                f"Bayes filter: prediction_lc needs at least 2 values (virtual place, loop), got {list(prediction_lc)}"
            )
        if not 0.0 <= virtual_place_prior <= 1.0:
            raise SlamError(f"Bayes filter: virtual_place_prior={virtual_place_prior} is not in [0, 1]")
        self.prediction_lc = tuple(float(v) for v in prediction_lc)
        self.virtual_place_prior = float(virtual_place_prior)
        self._posterior: dict[int, float] = {}

    @property
    def posterior(self) -> dict[int, float]:
        """Last posterior: hypothesis id (``VIRTUAL_PLACE`` included) -> probability."""
        return dict(self._posterior)

    def reset(self) -> None:
        """Forget the posterior (e.g. after relocalisation in another session)."""
        self._posterior = {}

    def _neighborhood(self, start: int, linked: Callable[[int], list[int]]) -> dict[int, int]:
        """Locations within the model's depth from ``start`` through ``linked`` (a location's links to the
        hypotheses' locations): id -> depth."""
        max_depth = len(self.prediction_lc) - 2
        depth = {start: 0}
        queue = deque([start])
        while queue:
            current = queue.popleft()
            d = depth[current]
            if d >= max_depth:
                continue
            for other in linked(current):
                if other not in depth:
                    depth[other] = d + 1
                    queue.append(other)
        return depth

    def predict(self, ids: Sequence[int], previous: Mapping[int, float], neighbors: NeighborFn) -> dict[int, float]:
        """``prior = P · previous`` over ``ids`` (locations, ascending) plus the virtual place."""
        locations = [i for i in ids if i != VIRTUAL_PLACE]
        n = len(locations)
        index = {loc: k for k, loc in enumerate(locations)}
        id_set = set(locations)
        prior = np.zeros(n)
        prior_vp = 0.0
        uniform_total = 0.0  # mass spread uniformly over every location (corrected below where it must not go)

        p_vp = previous.get(VIRTUAL_PLACE, 0.0)
        if n == 0:
            prior_vp = p_vp
        else:
            prior_vp += self.virtual_place_prior * p_vp
            uniform_total += (1.0 - self.virtual_place_prior) * p_vp / n

        # Each location's links among the hypotheses, looked up once per prediction: the walks from every location
        # reach the same few neighbours again and again (a working memory of 300 asked for each ~9 times).
        links: dict[int, list[int]] = {}

        def linked(location: int) -> list[int]:
            found = links.get(location)
            if found is None:
                found = links[location] = [other for other in neighbors(location) if other in id_set]
            return found

        for loc in locations:
            p = previous.get(loc, 0.0)
            if p == 0.0:
                continue
            depth = self._neighborhood(loc, linked)
            values = {other: self.prediction_lc[1 + d] for other, d in depth.items()}
            total = self.prediction_lc[0] + sum(values.values())
            others = n - len(values)
            spread = 0.0
            if total > 1.0 or others == 0:
                scale = 1.0 / total
            else:
                scale = 1.0
                spread = (1.0 - total) / others
            prior_vp += self.prediction_lc[0] * scale * p
            if spread > 0.0:
                uniform_total += spread * p
                for other in values:
                    prior[index[other]] -= spread * p
            for other, value in values.items():
                prior[index[other]] += value * scale * p
        prior += uniform_total
        out = {loc: float(prior[k]) for k, loc in enumerate(locations)}
        out[VIRTUAL_PLACE] = float(prior_vp)
        return out

    def compute_posterior(self, likelihood: Mapping[int, float], neighbors: NeighborFn) -> dict[int, float]:
        """One filter step; ``likelihood`` holds every WM location and ``VIRTUAL_PLACE``.

        ``neighbors(id)`` gives the ids linked to a location (odometry and loop links); only links between
        locations of ``likelihood`` count. Returns the new posterior.
        """
        if VIRTUAL_PLACE not in likelihood:
            raise SlamError("Bayes filter: the likelihood has no virtual place entry (id -1)")
        ids = sorted(likelihood)
        first = not self._posterior
        previous = {i: (1.0 if first else self._posterior.get(i, 0.0)) for i in ids}
        prior = self.predict(ids, previous, neighbors)
        posterior = {i: likelihood[i] * prior[i] for i in ids}
        total = sum(posterior.values())
        if total > 0:
            posterior = {i: v / total for i, v in posterior.items()}
        self._posterior = posterior
        return dict(posterior)
