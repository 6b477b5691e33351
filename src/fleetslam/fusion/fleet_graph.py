"""The fleet back-end: one pose graph over every agent's keyframes, optimised jointly and robustly (GTSAM GNC).

Each agent optimises its own keyframe graph in its own map frame and publishes it as deltas
(:mod:`fleetslam.fusion.graph_exchange`), with the inter-agent closures it verified (``INTER_AGENT`` constraints:
its keyframe ``from_id`` sees keyframe ``to_id`` of ``to_agent``'s run ``to_epoch``). :class:`FleetGraph` mirrors
every agent's graph and solves for every keyframe's pose in the fleet frame (the reference agent's map frame:
configured, by default the alphabetically first agent):

- **intra-agent**: a ``BetweenFactorPose3`` between consecutive keyframes from the agent's own optimised poses
  (its odometry and loops already in them), a known inlier;
- **inter-agent**: a ``BetweenFactorPose3`` per closure (the same pair of keyframes reported by both agents counts
  once), judged by GNC with a truncated-least-squares loss (``GncLMOptimizer``): a closure on repeated structure
  that the rest of the graph disputes gets weight 0;
- a prior on the reference agent's first keyframe (the fleet frame) and a weak one on every other agent's first
  keyframe (so an agent whose closures GNC all rejected is not an indeterminate system).

Only agents connected to the reference by closures are placed. A pair of agents is connected once its closures
pass the pairwise-consistency test the agents use themselves (:class:`~fleetslam.fusion.consistency.ClosureSet`:
enough mutually consistent closures, at more than one place of either agent, unrivalled: each agent counts the
places on its own keyframes, and the pair is connected when either would be); its rigid fit places a newly connected
agent (initial values), after which the previous solution warm-starts every solve.

Incremental and budgeted: :meth:`FleetGraph.solve` does nothing when no graph changed since the last solve and no
closure waits for a verdict. A closure between connected agents is used only once GNC judged it. GNC runs on a group
of agents, not on the whole fleet: those whose closures have waited longest, as many as ``gnc_budget`` keyframe
variables hold (at least one closure's two agents; a closure is taken once one of its agents is placed or taken),
then, while the budget holds, the placed agents joined to them by closures (breadth first: a fleet that fits is
judged as one), with every closure touching them judged (again, for the old ones) and the other agents' keyframes
they join held where the last solve placed them; a closure waiting beyond the budget is judged in a later solve
(``pending``), and an agent whose first closures wait is placed once they are judged. Then plain
Levenberg–Marquardt over every placed agent with the closures GNC kept, warm-started from the previous solve's result
(new keyframes start where their predecessor's correction, or their agent's placement, puts them): one step of it,
as iSAM2 takes one per update, and while that step still lowered the error the next solve goes on from there (so a
graph that stopped changing still converges); only the first solve (nothing to start from) iterates to
convergence. So one solve's work is bounded however many agents change at once (in ``benchmarks/fleet_backend.py``
every agent's closures arrive together, and one GNC over all 32 agents, 1700 variables, took 0.7 s, every agent's new
keyframes waiting meanwhile). The caller bounds the rate.

What a solve costs is the linear solve of that step (60–120 ms at 32 agents, 2700 variables) and Python around it:
every agent's keyframes are kept as arrays per version of its graph, its odometry factors and each closure's factor
are made once, the result is read out at once (``gtsam.utilities.extractPose3``) and the keyframes between the
variables of every agent are interpolated in one batch (per keyframe, in Python, these took more than the
optimisation itself).

Why a batch solve and not iSAM2: the agents re-optimise their own graphs (a loop closure moves every keyframe of
that agent), which changes every intra-agent factor of that agent; iSAM2 would have to remove and re-add them all,
and GNC has no incremental form anyway. A warm-started batch solve of a chain-like graph is linear in the number
of keyframes (``benchmarks/fleet_backend.py`` measures it at 32 agents).

Pure: no middleware. Poses are 4×4 ``T_map_camera`` (own map frame) or ``T_fleet_camera``.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Iterable
from dataclasses import dataclass, field
from functools import cached_property
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from fleetslam._imports import require
from fleetslam.fusion.consistency import ClosureSet, ConsistencyTolerance, Decision, PairClosure, fit_frames
from fleetslam.fusion.graph_exchange import GraphMirror, GraphUpdate
from fleetslam.geometry import invert, skew

log = logging.getLogger(__name__)

Pose = NDArray[np.float64]
ClosureKey = tuple[str, int, str, int]
"""``(agent_a, id_a, agent_b, id_b)`` with ``(agent_a, id_a) < (agent_b, id_b)``: one pair of keyframes."""

_SLOT_BITS = 32
"""A variable's key is ``slot << 32 | keyframe id``: each (re-)added agent gets a new slot."""


def _gtsam() -> Any:
    return require("gtsam", "slam")


@dataclass(frozen=True)
class ClosureReport:
    """An inter-agent closure as an agent published it: its keyframe ``from_id`` sees ``to_agent``'s ``to_id``."""

    from_agent: str
    from_id: int
    to_agent: str
    to_id: int
    relative: Pose
    """``T_fromcamera_tocamera``."""
    to_epoch: int
    """The run of ``to_agent`` that ``to_id`` belongs to."""
    covariance: Pose | None = None
    """6×6 covariance of ``relative`` as its agent estimated it (translation first, perturbation on the right:
    ``relative · exp(ξ)``); None: unknown (``FleetGraph.closure_sigma`` stands in)."""

    @cached_property
    def oriented(self) -> FleetClosure:
        """The closure as :class:`FleetClosure` (computed once: the fleet graph looks at every closure every solve)."""
        return FleetClosure.of(self)


@dataclass(frozen=True)
class FleetClosure:
    """One pair of keyframes of two agents, oriented so that ``(a, a_id) < (b, b_id)``."""

    a: str
    a_id: int
    b: str
    b_id: int
    relative: Pose
    """``T_acamera_bcamera``."""
    covariance: Pose | None = None
    """Of ``relative``, as :attr:`ClosureReport.covariance`."""

    @property
    def key(self) -> ClosureKey:
        return (self.a, self.a_id, self.b, self.b_id)

    @classmethod
    def of(cls, report: ClosureReport) -> FleetClosure:
        if (report.from_agent, report.from_id) <= (report.to_agent, report.to_id):
            return cls(report.from_agent, report.from_id, report.to_agent, report.to_id, report.relative,
                       report.covariance)  # fmt: skip
        covariance = None
        if report.covariance is not None:  # (T·exp(ξ))⁻¹ = T⁻¹·exp(−Ad_T·ξ)
            adjoint = _adjoint(report.relative)
            covariance = adjoint @ report.covariance @ adjoint.T
        return cls(report.to_agent, report.to_id, report.from_agent, report.from_id, invert(report.relative),
                   covariance)  # fmt: skip


@dataclass(frozen=True)
class AgentPlacement:
    """Where the joint optimisation puts one agent."""

    T_fleet_map: Pose
    """Rigid fit of its corrected keyframe poses to its own ones: ``corrected ≈ T_fleet_map · own``."""
    ids: NDArray[np.int64]
    """Its keyframes' ids, ascending."""
    stack: NDArray[np.float64]
    """Their corrected ``T_fleet_camera``, (N, 4, 4) in the order of ``ids``."""
    stamp_array: NDArray[np.float64]
    """Their stamps (s), in the order of ``ids``."""

    @cached_property
    def poses(self) -> dict[int, Pose]:
        """Keyframe id -> corrected ``T_fleet_camera``."""
        return dict(zip(self.ids.tolist(), self.stack, strict=True))

    @cached_property
    def stamps(self) -> dict[int, float]:
        """Keyframe id -> stamp (s)."""
        return dict(zip(self.ids.tolist(), self.stamp_array.tolist(), strict=True))

    def moved(self, T: Pose) -> AgentPlacement:
        """The placement expressed in another frame: ``T ·`` every pose."""
        return AgentPlacement(T @ self.T_fleet_map, self.ids, np.matmul(T, self.stack), self.stamp_array)


@dataclass(frozen=True)
class FleetSolution:
    """The outcome of one :meth:`FleetGraph.solve`."""

    placements: dict[str, AgentPlacement]
    """The agents placed in the fleet frame (the reference among them)."""
    kept: list[FleetClosure]
    """Closures between placed agents that GNC believes."""
    rejected: list[FleetClosure]
    """Closures between placed agents that GNC gave weight 0."""
    robust: bool
    """GNC judged closures in this solve; else only Levenberg–Marquardt with the ``kept`` closures."""
    keyframes: int
    """Variables of the solve."""
    seconds: float
    """Wall time of the solve (building the graph included)."""
    cpu_seconds: float = 0.0
    """CPU time of the solving thread (what the solve costs, whatever else the machine runs)."""
    pending: list[FleetClosure] = field(default_factory=list)
    """Closures between connected agents that wait for GNC's verdict (the next solves judge them; not used yet)."""
    gnc_variables: int = 0
    """Variables of this solve's GNC (0: none ran); at most ``gnc_budget`` unless one closure's agents need more."""


@dataclass(frozen=True)
class _Keyframes:
    """An agent's own keyframes as arrays (ascending ids): what every solve reads of its graph."""

    ids: NDArray[np.int64]
    poses: NDArray[np.float64]
    """``T_map_camera``, (N, 4, 4)."""
    stamps: NDArray[np.float64]


@dataclass
class _Agent:
    mirror: GraphMirror[ClosureReport]
    slot: int
    restarts: int = 0
    _keyframes: _Keyframes | None = None
    _version: tuple[int, int, int, int] = (0, 0, 0, 0)
    odometry: dict[bytes, Any] = field(default_factory=dict)
    """Its chain's odometry factors (a ``NonlinearFactorGraph``) by the chain's positions, for this version of its
    graph: rebuilding them every solve for every agent cost more than the optimisation."""

    def keyframes(self) -> _Keyframes:
        """Its keyframes as arrays, made again only when its graph changed."""
        mirror = self.mirror
        version = (mirror.epoch, mirror.sequence, len(mirror.poses), id(mirror.poses))
        if self._keyframes is None or version != self._version:
            ids = sorted(mirror.poses)
            poses = np.stack([mirror.poses[i] for i in ids]) if ids else np.zeros((0, 4, 4))
            stamps = np.array([mirror.stamps.get(i, 0.0) for i in ids], dtype=np.float64)
            self._keyframes = _Keyframes(np.array(ids, dtype=np.int64), poses, stamps)
            self._version = version
            self.odometry.clear()
        return self._keyframes


@dataclass
class FleetGraph:
    """Every agent's keyframe graph and inter-agent closures in, one placement per agent out (module docstring)."""

    reference: str = ""
    """The agent whose map frame is the fleet frame; empty: the alphabetically first agent known."""
    odometry_sigma: tuple[float, float] = (0.01, 0.005)
    """Standard deviation (m, rad) of the relative pose of two consecutive keyframes of one agent (from its own
    optimised graph: millimetres apart over a keyframe's 25 cm in the benchmarks; 5 cm let imprecise closures bend
    the agents' chains, the reference's included: 3-agent joint fleet ATE 7.4 cm against 1.7 cm now)."""
    closure_sigma: tuple[float, float] = (0.05, 0.02)
    """Standard deviation (m, rad) of an inter-agent closure that comes without its covariance."""
    closure_sigma_floor: tuple[float, float] = (0.01, 0.005)
    """Standard deviation (m, rad) added (in quadrature) to a closure's own covariance: its two keyframes' poses in
    their agents' graphs are not exact either (``odometry_sigma`` of one keyframe)."""
    inlier_probability: float = 0.99
    """GNC's inlier threshold: a closure whose whitened error exceeds this quantile of χ²(6) is an outlier."""
    max_iterations: int = 20
    """Levenberg–Marquardt iterations of a solve with nothing to start from (each GNC step too)."""
    warm_iterations: int = 1
    """Levenberg–Marquardt iterations of a solve that starts from the previous one's result (iSAM2 likewise takes one
    step per update; an agent newly placed starts where GNC's judging solve put it): from there one step reaches the
    optimum to a few parts in 10⁶ of the error (32 agents of ``benchmarks/fleet_backend.py``: 2700 variables,
    215.107 → 211.247 after one step and after two), and each step of a graph that large costs 60–120 ms of CPU. A
    step that still lowered the error by more than ``relative_error_tol`` and ``absolute_error_tol`` is followed by
    another solve, so a graph that stopped changing still converges."""
    relative_error_tol: float = 1e-5
    """Relative decrease of the error under which a solve counts as converged (GTSAM's default)."""
    absolute_error_tol: float = 1e-5
    """Decrease of the error under which a solve counts as converged, whatever the error (GTSAM's default)."""
    gnc_budget: int = 200
    """Most variables of one solve's GNC: closures waiting for a verdict are judged a group of agents at a time
    (those waiting longest first, as many agents as this many of their keyframe variables hold, at least the two of
    one closure; then their placed neighbours while it holds), the rest in the next solves; see the module
    docstring."""
    coarse_stride: int = 5
    """Of an agent's older keyframes, every ``coarse_stride``-th is a variable (and every closure's keyframe); the
    ones between follow their corrections. 1: every keyframe is a variable."""
    recent_keyframes: int = 10
    """An agent's newest keyframes that are all variables."""
    tolerance: ConsistencyTolerance = field(default_factory=ConsistencyTolerance)
    """Pairwise consistency of two agents' closures (see :class:`ClosureSet`)."""
    min_closures: int = 3
    min_places: int = 2
    dominance: float = 2.0
    agents: dict[str, _Agent] = field(default_factory=dict)
    changed: bool = False
    """A graph changed since the last solve."""
    _next_slot: int = 1
    _pairs: dict[tuple[str, str], ClosureSet] = field(default_factory=dict)
    _decisions: dict[tuple[str, str], Decision] = field(default_factory=dict)
    _in_pairs: set[ClosureKey] = field(default_factory=set)
    _solution: dict[str, AgentPlacement] = field(default_factory=dict)
    _verdicts: dict[ClosureKey, bool] = field(default_factory=dict)
    """GNC's last verdict on each closure it judged (True: kept); the others wait for one."""
    _pending_since: dict[ClosureKey, int] = field(default_factory=dict)
    """The solve a closure waiting for a verdict was first seen in (the longest waiting are judged first)."""
    _solves: int = 0
    _odometry_noise: dict[int, Any] = field(default_factory=dict)
    """Noise model of an odometry factor over this many keyframe steps."""
    _solved_reference: str | None = None
    _warm: Any = None
    """The last solve's result (``gtsam.Values``, before its re-expression in the fleet frame): the next one starts
    from it, all its variables at once."""
    _closure_factors: dict[int, tuple[FleetClosure, tuple[int, int], Any]] = field(default_factory=dict)
    """``id(closure)`` -> the closure, its agents' slots and its factor (made once: the noise model of a closure's
    covariance is costly, and every solve adds every closure)."""

    # -- input ---------------------------------------------------------------------------------------------------
    def apply(self, agent: str, update: GraphUpdate[ClosureReport]) -> bool:
        """Apply an agent's graph update (only its ``INTER_AGENT`` constraints, as :class:`ClosureReport`); False
        when the agent's full graph must be requested (a gap). A new epoch (the agent restarted its SLAM: a new
        map frame) drops the agent and adds it again."""
        state = self.agents.get(agent)
        if state is not None and state.mirror.epoch not in (0, update.epoch):
            restarts = state.restarts + 1
            self.drop(agent)
            log.info("%s restarted (epoch %d): dropped and added again", agent, update.epoch)
            state = None
        else:
            restarts = 0 if state is None else state.restarts
        if state is None:
            state = self.agents[agent] = _Agent(GraphMirror(), self._next_slot, restarts)
            self._next_slot += 1
        synced = state.mirror.apply(update)
        self.changed = True
        return synced

    def drop(self, agent: str) -> None:
        """Forget an agent: its keyframes, its closures and its place (the reference: everyone's place)."""
        was_reference = agent == self.reference_agent()
        if self.agents.pop(agent, None) is None:
            return
        for pair in [p for p in self._pairs if agent in p]:
            del self._pairs[pair]
            self._decisions.pop(pair, None)
        self._in_pairs = {k for k in self._in_pairs if agent not in (k[0], k[2])}
        self._solution.pop(agent, None)
        # Its next run's closures may reuse the same keyframe ids: judged afresh.
        self._verdicts = {k: v for k, v in self._verdicts.items() if agent not in (k[0], k[2])}
        if was_reference:
            self._solution.clear()  # the fleet frame itself is new
            self._warm = None
        self.changed = True

    def reference_agent(self) -> str | None:
        """The agent whose map frame is the fleet frame, once it is known."""
        if self.reference:
            return self.reference
        return min(self.agents) if self.agents else None

    def unsynced(self) -> list[str]:
        """Agents whose graph has a gap (their full graph is needed)."""
        return sorted(a for a, state in self.agents.items() if not state.mirror.synced)

    def restarts(self, agent: str) -> int:
        """Times ``agent`` was seen to restart."""
        state = self.agents.get(agent)
        return state.restarts if state is not None else 0

    # -- closures and placement -----------------------------------------------------------------------------------
    def closures(self) -> dict[ClosureKey, FleetClosure]:
        """The valid closures: of agents' current runs, both keyframes known (the first report of a pair wins)."""
        found: dict[ClosureKey, FleetClosure] = {}
        for agent in sorted(self.agents):
            for report in self.agents[agent].mirror.constraints:
                target = self.agents.get(report.to_agent)
                if report.from_agent != agent or target is None or target.mirror.epoch != report.to_epoch:
                    continue
                if report.from_id not in self.agents[agent].mirror.poses or report.to_id not in target.mirror.poses:
                    continue
                closure = report.oriented
                found.setdefault(closure.key, closure)
        return found

    def _update_pairs(self, closures: Iterable[FleetClosure]) -> None:
        """New closures into their pair's consistency test, while the pair is not placed in one solution (then GNC
        judges its closures, and the test's cost, growing with the closures it holds, is saved)."""
        for closure in closures:
            if closure.key in self._in_pairs:
                continue
            self._in_pairs.add(closure.key)
            if closure.a in self._solution and closure.b in self._solution:
                continue
            pair = (closure.a, closure.b)
            closure_set = self._pairs.get(pair)
            if closure_set is None:
                closure_set = self._pairs[pair] = ClosureSet(
                    tolerance=self.tolerance, min_inliers=self.min_closures, min_places=self.min_places,
                    dominance=self.dominance, places_either_side=True,
                )  # fmt: skip
            own, peer = self.agents[closure.a].mirror.poses, self.agents[closure.b].mirror.poses
            if closure_set.add(PairClosure(closure.a_id, closure.b_id, own[closure.a_id], peer[closure.b_id],
                                           closure.relative)):  # fmt: skip
                self._decisions[pair] = closure_set.decide()

    def connected(self) -> dict[str, Pose]:
        """``T_fleet_map`` of every agent the pairwise-consistent closures connect to the reference (breadth first,
        from the pairs' rigid fits): the placement of agents not solved before."""
        reference = self.reference_agent()
        if reference is None or reference not in self.agents:
            return {}
        edges: dict[str, list[tuple[str, Pose]]] = {}
        for (a, b), decision in sorted(self._decisions.items()):
            if decision.alignment is not None and a in self.agents and b in self.agents:
                edges.setdefault(a, []).append((b, decision.alignment))
                edges.setdefault(b, []).append((a, invert(decision.alignment)))
        placed = {reference: np.eye(4)}
        frontier = [reference]
        while frontier:
            agent = frontier.pop(0)
            for other, T_agent_other in edges.get(agent, []):
                if other not in placed:
                    placed[other] = placed[agent] @ T_agent_other
                    frontier.append(other)
        return placed

    # -- the solve ------------------------------------------------------------------------------------------------
    def solve(self) -> FleetSolution | None:
        """Re-optimise if a graph changed since the last solve, or closures still wait for a verdict (else None); see
        the module docstring."""
        if not self.changed:
            return None
        self.changed = False
        self._solves += 1
        started, started_cpu = time.perf_counter(), time.thread_time()
        reference = self.reference_agent()
        if reference != self._solved_reference:
            # The fleet frame is another agent's map frame now (an alphabetically earlier agent appeared, or the
            # reference restarted): the previous solution is in the old frame and must not warm-start the new one.
            self._solution, self._verdicts, self._pending_since, self._warm = {}, {}, {}, None
            self._solved_reference = reference
        closures = self.closures()
        if len(self._closure_factors) > 2 * len(closures):  # closures of agents dropped or restarted
            valid = {id(c) for c in closures.values()}
            self._closure_factors = {k: v for k, v in self._closure_factors.items() if k in valid}
        self._update_pairs(closures.values())
        connected = self.connected()
        candidates = {a for a in connected if self.agents[a].mirror.poses}
        if reference not in candidates:
            self._solution, self._warm = {}, None
            return FleetSolution({}, [], [], False, 0, time.perf_counter() - started, time.thread_time() - started_cpu)
        between = [c for c in closures.values() if c.a in candidates and c.b in candidates and c.a != c.b]
        self._verdicts = {k: v for k, v in self._verdicts.items() if k in closures}
        waiting = [c for c in between if c.key not in self._verdicts]
        self._pending_since = {c.key: self._pending_since.get(c.key, self._solves) for c in waiting}
        placed = {a for a in self._solution if a in candidates} | {reference}
        group = self._group(sorted(waiting, key=lambda c: (self._pending_since[c.key], c.key)), placed, between)
        judged = [c for c in between if (c.a in group or c.b in group) and self._judgeable(c, group)]
        group &= {a for c in judged for a in (c.a, c.b)}  # an agent is placed once a closure of it was judged
        initial = {a: p.T_fleet_map for a, p in self._solution.items() if a in candidates}
        initial.update({a: connected[a] for a in placed | group if a not in initial})
        gnc_variables = 0
        if judged:
            judged_fits, gnc_variables = self._judge(sorted(group), judged, initial, reference)
            initial.update({a: fit for a, fit in judged_fits.items() if a not in self._solution})
        placed |= group
        used = [c for c in between if c.a in placed and c.b in placed and self._verdicts.get(c.key, False)]
        g = _gtsam()
        graph = g.NonlinearFactorGraph()
        values = g.Values(self._warm) if self._warm is not None else g.Values()
        warm = np.asarray(values.keys(), dtype=np.int64)
        endpoints = _endpoints(used)
        agents = sorted(placed)
        chains = [self._add_chain(graph, values, agent, endpoints.get(agent, set()), initial[agent], reference,
                                  warm=warm)
                  for agent in agents]  # fmt: skip
        own = [self.agents[agent].keyframes() for agent in agents]
        chain_keys = [
            self._keys(agent, keyframes.ids[chain]) for agent, keyframes, chain in zip(agents, own, chains, strict=True)
        ]
        for key in np.setdiff1d(warm, np.concatenate(chain_keys)).tolist():  # no longer a variable
            values.erase(key)
        self._add_closures(graph, used)
        iterations = self.max_iterations if self._warm is None else self.warm_iterations
        optimizer = g.LevenbergMarquardtOptimizer(graph, values, self._lm_params(iterations))
        start_error = optimizer.error()
        result = optimizer.optimize()
        decrease = start_error - optimizer.error()
        converging = decrease > self.relative_error_tol * start_error and decrease > self.absolute_error_tol
        if iterations < self.max_iterations and converging:
            self.changed = True  # the next solve goes on from here
        self._warm = result
        solved = _Solved.of(result)
        solved_chains = [solved.poses(keys) for keys in chain_keys]
        corrected = _fill_between([k.poses for k in own], chains, solved_chains)
        solution = {
            agent: AgentPlacement(fit_frames(keyframes.poses[chain], solved_chain), keyframes.ids, poses,
                                  keyframes.stamps)
            for agent, keyframes, chain, solved_chain, poses in zip(agents, own, chains, solved_chains, corrected,
                                                                strict=True)
        }  # fmt: skip
        # The fleet frame is the reference's map frame: its own rigid fit is the identity by definition. The solve
        # bends its chain too (the prior holds its first keyframe only), and that fit moved by centimetres and
        # tenths of a degree from solve to solve, re-landing every map with it; everything is re-expressed so that
        # the reference's fit stays the identity and only the others' placements move relative to it.
        to_fleet = invert(solution[reference].T_fleet_map)
        solution = {agent: placement.moved(to_fleet) for agent, placement in solution.items()}
        self._solution = solution
        among = [c for c in between if c.a in placed and c.b in placed]
        kept = [c for c in among if self._verdicts.get(c.key) is True]
        rejected = [c for c in among if self._verdicts.get(c.key) is False]
        pending = [c for c in between if c.key not in self._verdicts]
        self.changed = self.changed or bool(pending)  # the rest are judged in the next solves
        return FleetSolution(solution, kept, rejected, bool(judged), int(values.size()),
                             time.perf_counter() - started, time.thread_time() - started_cpu, pending,
                             gnc_variables)  # fmt: skip

    def _group(self, waiting: list[FleetClosure], placed: set[str], between: list[FleetClosure]) -> set[str]:
        """The agents whose closures this solve judges: those of the closures waiting longest (``waiting`` is in that
        order), as many as ``gnc_budget`` variables hold (at least one closure's); a closure is taken only when one of
        its agents is placed or taken already (the others are held where they are placed). Then, within the budget,
        the placed agents joined to them by closures, breadth first."""
        endpoints = _endpoints(between)
        size = {a: len(self._chain(self.agents[a].keyframes().ids, endpoints.get(a, set()))) for a in endpoints}
        group: set[str] = set()
        variables, grew = 0, True
        while grew:  # again: a closure anchored by an agent taken after it was looked at
            grew = False
            for c in waiting:
                new = {c.a, c.b} - group
                if not new or not {c.a, c.b} & (placed | group):
                    continue
                cost = sum(size[a] for a in new)
                if group and variables + cost > self.gnc_budget:
                    continue
                group |= new
                variables += cost
                grew = True
        # Room left: the placed agents that share closures with the group are solved too, not held (nearest first),
        # so that their closures are judged with more of the graph free; a fleet that fits is judged as one.
        frontier = sorted(group)
        while frontier and group:
            agent = frontier.pop(0)
            for c in between:
                other = c.b if c.a == agent else c.a if c.b == agent else None
                if other is None or other in group or other not in placed:
                    continue
                if variables + size[other] <= self.gnc_budget:
                    group.add(other)
                    variables += size[other]
                    frontier.append(other)
        return group

    def _judgeable(self, closure: FleetClosure, group: set[str]) -> bool:
        """Both of the closure's keyframes are variables of the group's GNC or placed by the last solve (held)."""
        return all(agent in group or (agent in self._solution and i in self._solution[agent].poses)
                   for agent, i in ((closure.a, closure.a_id), (closure.b, closure.b_id)))  # fmt: skip

    def _judge(
        self, group: list[str], closures: list[FleetClosure], initial: dict[str, Pose], reference: str
    ) -> tuple[dict[str, Pose], int]:
        """GNC (truncated least squares) over ``group``'s keyframes and ``closures`` (each touching the group), the
        other agents' keyframes held where the last solve put them, odometry known inliers: a verdict on each closure.
        Returns the group's placements (rigid fits of the solved chains) and the variables solved."""
        g = _gtsam()
        graph, values = g.NonlinearFactorGraph(), g.Values()
        endpoints = _endpoints(closures)
        chains = {agent: self._add_chain(graph, values, agent, endpoints.get(agent, set()), initial[agent], reference,
                                         as_placed=True)
                  for agent in group}  # fmt: skip
        held = g.noiseModel.Isotropic.Sigma(6, 1e-4)
        for c in closures:
            for agent, i in ((c.a, c.a_id), (c.b, c.b_id)):
                key = self._key(agent, i)
                if agent not in chains and not values.exists(key):
                    pose = g.Pose3(self._solution[agent].poses[i])
                    values.insert(key, pose)
                    graph.add(g.PriorFactorPose3(key, pose, held))
        known = int(graph.size())
        self._add_closures(graph, closures)
        params = g.GncLMParams(self._lm_params())
        params.setLossType(g.GncLossType.TLS)
        params.setKnownInliers(list(range(known)))
        optimizer = g.GncLMOptimizer(graph, values, params)
        optimizer.setInlierCostThresholdsAtProbability(self.inlier_probability)
        result = optimizer.optimize()
        weights = np.asarray(optimizer.getWeights())[known:]
        self._verdicts.update({c.key: bool(w > 0.5) for c, w in zip(closures, weights, strict=True)})
        solved = _Solved.of(result)
        fits = {}
        for agent, chain in chains.items():
            own = self.agents[agent].keyframes()
            fits[agent] = fit_frames(own.poses[chain], solved.poses(self._keys(agent, own.ids[chain])))
        return fits, sum(len(chain) for chain in chains.values())

    def _add_chain(self, graph: Any, values: Any, agent: str, endpoints: set[int], T_fleet_map: Pose,
                   reference: str, *, as_placed: bool = False, warm: NDArray[np.int64] | None = None
                   ) -> NDArray[np.intp]:  # fmt: skip
        """``agent``'s keyframe chain into ``graph``: its variables (warm-started from the last solution, new ones
        where ``T_fleet_map`` puts them), the odometry between them, the prior on its first one (the reference's: its
        own pose, or with ``as_placed`` where the last solution put it, the frame the agents held there are in).
        ``warm``: keys (ascending) that ``values`` holds already, from the last solve's result; a new keyframe between
        them starts where its predecessor's correction puts it. Returns the chain: positions in the agent's
        :meth:`_Agent.keyframes`."""
        g = _gtsam()
        state = self.agents[agent]
        own = state.keyframes()
        chain = self._chain(own.ids, endpoints)
        ids = own.ids[chain]
        guesses = np.matmul(T_fleet_map, own.poses[chain])
        previous = self._solution.get(agent)
        known = np.zeros(len(chain), dtype=bool)
        if previous is not None and len(previous.ids):
            rows = np.minimum(np.searchsorted(previous.ids, ids), len(previous.ids) - 1)
            known = previous.ids[rows] == ids
            guesses[known] = previous.stack[rows[known]]
        keys = self._keys(agent, ids).tolist()
        fresh = np.ones(len(chain), dtype=bool) if warm is None else ~np.isin(keys, warm)
        for k in np.flatnonzero(fresh).tolist():
            guess = guesses[k]
            if k > 0 and not fresh[k - 1]:  # its predecessor as the last solve left it, moved as its own graph says
                before = np.asarray(values.atPose3(keys[k - 1]).matrix())
                guess = before @ invert(own.poses[chain[k - 1]]) @ own.poses[chain[k]]
            values.insert(keys[k], g.Pose3(guess))
        if agent == reference:
            anchor = guesses[0] if as_placed and known[0] else own.poses[chain[0]]
            graph.add(g.PriorFactorPose3(keys[0], g.Pose3(anchor), g.noiseModel.Isotropic.Sigma(6, 1e-4)))
        else:
            graph.add(g.PriorFactorPose3(keys[0], g.Pose3(guesses[0]), g.noiseModel.Isotropic.Sigma(6, 100.0)))
        graph.push_back(self._odometry(agent, chain))
        return chain

    def _odometry(self, agent: str, chain: NDArray[np.intp]) -> Any:
        """The odometry factors between consecutive keyframes of ``chain`` (positions in ``agent``'s keyframes), from
        the agent's own poses; made once per version of its graph and chain."""
        state = self.agents[agent]
        cache_key = chain.tobytes()
        factors = state.odometry.get(cache_key)
        if factors is not None:
            return factors
        g = _gtsam()
        own = state.keyframes()
        factors = g.NonlinearFactorGraph()
        keys = self._keys(agent, own.ids[chain]).tolist()
        spans = np.diff(chain).tolist()
        for a, b, span, relative in zip(keys[:-1], keys[1:], spans, _steps(own.poses[chain]), strict=True):
            if span not in self._odometry_noise:  # the steps' errors add up: sigma grows with their square root
                self._odometry_noise[span] = g.noiseModel.Diagonal.Sigmas(_sigmas(self.odometry_sigma) * np.sqrt(span))
            factors.add(g.BetweenFactorPose3(a, b, g.Pose3(relative), self._odometry_noise[span]))
        if len(state.odometry) >= 4:  # the solve's chain and GNC's (other closures' keyframes) alternate
            state.odometry.clear()
        state.odometry[cache_key] = factors
        return factors

    @property
    def solution(self) -> dict[str, AgentPlacement]:
        """The agents placed by the last solve."""
        return self._solution

    def _chain(self, ids: NDArray[np.int64], endpoints: set[int]) -> NDArray[np.intp]:
        """Positions in ``ids`` (ascending) of the keyframes solved for: the first, the ``recent_keyframes`` newest,
        every ``coarse_stride``-th and every closure's; the others follow the solved ones on either side."""
        position = np.arange(len(ids))
        keep = (position % self.coarse_stride == 0) | (position >= len(ids) - self.recent_keyframes)
        if endpoints:
            keep |= np.isin(ids, np.fromiter(endpoints, dtype=np.int64, count=len(endpoints)))
        return np.flatnonzero(keep)

    def _add_closures(self, graph: Any, closures: Iterable[FleetClosure]) -> None:
        """One ``BetweenFactorPose3`` per closure, with its own covariance (plus ``closure_sigma_floor``), or
        ``closure_sigma`` when it came without one: an imprecise closure weighs less, and GNC judges it by its own
        uncertainty."""
        g = _gtsam()
        cache = self._closure_factors
        for c in closures:
            slots = (self.agents[c.a].slot, self.agents[c.b].slot)
            entry = cache.get(id(c))
            if entry is None or entry[0] is not c or entry[1] != slots:
                model = g.noiseModel.Diagonal.Sigmas(_sigmas(self.closure_sigma))
                if c.covariance is not None:
                    rotation_first = np.asarray(c.covariance, np.float64)[np.ix_(_ROTATION_FIRST, _ROTATION_FIRST)]
                    model = g.noiseModel.Gaussian.Covariance(
                        rotation_first + np.diag(_sigmas(self.closure_sigma_floor) ** 2)
                    )
                factor = g.BetweenFactorPose3(
                    self._key(c.a, c.a_id), self._key(c.b, c.b_id), g.Pose3(c.relative), model
                )
                entry = cache[id(c)] = (c, slots, factor)
            graph.add(entry[2])

    def _lm_params(self, iterations: int | None = None) -> Any:
        """Levenberg–Marquardt's parameters of every solve (GNC's inner steps too)."""
        lm = _gtsam().LevenbergMarquardtParams()
        lm.setMaxIterations(iterations or self.max_iterations)
        return lm

    def _key(self, agent: str, keyframe_id: int) -> int:
        return (self.agents[agent].slot << _SLOT_BITS) | int(keyframe_id)

    def _keys(self, agent: str, ids: NDArray[np.int64]) -> NDArray[np.int64]:
        return (self.agents[agent].slot << _SLOT_BITS) | ids


def _endpoints(closures: Iterable[FleetClosure]) -> dict[str, set[int]]:
    """Per agent, its keyframes that ``closures`` join to another agent's."""
    found: dict[str, set[int]] = {}
    for c in closures:
        found.setdefault(c.a, set()).add(c.a_id)
        found.setdefault(c.b, set()).add(c.b_id)
    return found


def _fill_between(
    own: list[NDArray[np.float64]], chains: list[NDArray[np.intp]], solved: list[NDArray[np.float64]]
) -> list[NDArray[np.float64]]:
    """Every keyframe's corrected pose, for each agent (``own``: its own poses, (N, 4, 4)): those of its chain
    (positions in ``own``, ascending) as solved; one between two solved keyframes moves by their corrections
    (``T_corrected · T_own⁻¹``) interpolated by its place between them (the newest are all solved). All agents at
    once: the rotations' interpolation costs more per call than per keyframe."""
    corrected, free, fractions, before, after = [], [], [], [], []
    for poses, chain, solved_chain in zip(own, chains, solved, strict=True):
        out = np.empty_like(poses)
        out[chain] = solved_chain
        corrected.append(out)
        between = np.setdiff1d(np.arange(len(poses)), chain)
        free.append(between)
        if not len(between):
            continue
        corrections = np.matmul(solved_chain, invert(poses[chain]))
        segment = np.searchsorted(chain, between) - 1
        fractions.append((between - chain[segment]) / (chain[segment + 1] - chain[segment]))
        before.append(corrections[segment])
        after.append(corrections[segment + 1])
    if not fractions:
        return corrected
    fraction, start, end = np.concatenate(fractions), np.concatenate(before), np.concatenate(after)
    turn = Rotation.from_matrix(np.swapaxes(start[:, :3, :3], 1, 2) @ end[:, :3, :3]).as_rotvec()
    moved = np.broadcast_to(np.eye(4), (len(fraction), 4, 4)).copy()
    moved[:, :3, :3] = start[:, :3, :3] @ Rotation.from_rotvec(turn * fraction[:, None]).as_matrix()
    moved[:, :3, 3] = (1.0 - fraction)[:, None] * start[:, :3, 3] + fraction[:, None] * end[:, :3, 3]
    offset = 0
    for out, poses, between in zip(corrected, own, free, strict=True):
        out[between] = moved[offset : offset + len(between)] @ poses[between]
        offset += len(between)
    return corrected


@dataclass(frozen=True)
class _Solved:
    """An optimiser's result as arrays: its keys (ascending) and their poses."""

    keys: NDArray[np.int64]
    stack: NDArray[np.float64]

    @classmethod
    def of(cls, result: Any) -> _Solved:
        rows = np.asarray(_gtsam().utilities.extractPose3(result), dtype=np.float64)  # in key order
        stack = np.broadcast_to(np.eye(4), (len(rows), 4, 4)).copy()
        stack[:, :3, :3] = rows[:, :9].reshape(-1, 3, 3)
        stack[:, :3, 3] = rows[:, 9:]
        return cls(np.asarray(result.keys(), dtype=np.int64), stack)

    def poses(self, keys: NDArray[np.int64]) -> NDArray[np.float64]:
        """The poses of ``keys`` (each must be in the result)."""
        return self.stack[np.searchsorted(self.keys, keys)]


def _steps(poses: list[Pose] | NDArray[np.float64]) -> NDArray[np.float64]:
    """``T_k⁻¹ · T_k+1`` of consecutive poses, all at once."""
    stack = np.asarray(poses, dtype=np.float64).reshape(-1, 4, 4)
    rotation_t = np.swapaxes(stack[:-1, :3, :3], 1, 2)
    steps = np.broadcast_to(np.eye(4), (len(poses) - 1, 4, 4)).copy()
    steps[:, :3, :3] = rotation_t @ stack[1:, :3, :3]
    steps[:, :3, 3] = np.einsum("kij,kj->ki", rotation_t, stack[1:, :3, 3] - stack[:-1, :3, 3])
    return steps


_ROTATION_FIRST = [3, 4, 5, 0, 1, 2]
"""Our 6-vectors are translation first, GTSAM's Pose3 tangent rotation first."""


def _adjoint(pose: Pose) -> NDArray[np.float64]:
    """``Ad_T`` on (translation, rotation) tangent vectors: ``T·exp(ξ)·T⁻¹ = exp(Ad_T·ξ)``."""
    rotation, translation = pose[:3, :3], pose[:3, 3]
    adjoint = np.zeros((6, 6))
    adjoint[:3, :3] = adjoint[3:, 3:] = rotation
    adjoint[:3, 3:] = skew(translation) @ rotation
    return adjoint


def _sigmas(sigma: tuple[float, float]) -> NDArray[np.float64]:
    """GTSAM's Pose3 tangent order: rotation first."""
    return np.array([sigma[1]] * 3 + [sigma[0]] * 3, dtype=np.float64)
