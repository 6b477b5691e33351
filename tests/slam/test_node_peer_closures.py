"""``slam/diagnostics`` counts, per peer, the inter-agent closures accepted and rejected (for the demo's report)."""

from __future__ import annotations

import numpy as np

from fleetslam.fusion.collaboration import InterAgentLinker
from fleetslam.slam.node import peer_closure_counts

from ..fusion.test_consistency import closure


def test_closures_on_repeated_structure_count_as_rejected_and_the_consistent_set_as_accepted() -> None:
    rng = np.random.default_rng(3)
    linker = InterAgentLinker("c3po")
    state = linker.peer("r2d2")
    for step in range(3):  # an aisle: one wrong (next module) and one right closure per step
        state.closures.add(closure(0.6 * step, 0.0, rng, shifted=True))
        state.closures.add(closure(0.6 * step + 0.3, 0.0, rng))
    state.decision = state.closures.decide()
    assert state.decision.alignment is None  # ambiguous: nothing accepted, the rival set is not rejected yet
    counts = peer_closure_counts(linker)
    assert counts == {"peer_closures_accepted.r2d2": 0, "peer_closures_rejected.r2d2": 3}
    for x, y in [(6.0, 4.0), (-3.0, 5.0), (8.0, -2.0), (-4.0, -4.0)]:  # places outside the aisle tell them apart
        state.closures.add(closure(x, y, rng))
    state.decision = state.closures.decide()
    assert state.decision.alignment is not None, state.decision.reason
    assert peer_closure_counts(linker) == {"peer_closures_accepted.r2d2": 7, "peer_closures_rejected.r2d2": 3}
    assert peer_closure_counts(InterAgentLinker("c3po")) == {}  # no peer seen yet: no keys
