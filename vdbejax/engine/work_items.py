"""The sequential strategy's work items: which agents run together, padded to what size.

Agents are split by kind and into about ``4 × threads`` items of similar cost
(:func:`sequential_groups`); an item's arrays are padded to a power of two rows, or to
one size for every item (:func:`common_rows`: one program for all), so few programs are
compiled. Padding rows never run. The grouping changes no result.
"""
from __future__ import annotations

import numpy as np

from vdbejax.engine.agent_state import state_bytes
from vdbejax.envs.tabular import TabularMDP
from vdbejax.methods.agents import AgentParams, table_layout

#: Agents one native step loop runs side by side, one vector lane each. Their steps are
#: independent (each lane reads and writes only its own agent's rows), so the width
#: changes the speed, not the results: the products are rounded on their own
#: (:mod:`vdbejax._numerics`), and widths 1, 2, 4, 8 and 16 give the same bits on the
#: paper grid (tests check 1, 2 and 4 against lockstep). Four were the fastest on the
#: 2-core AVX-512 machine (``benchmarks/RESULTS.md``). Work items are padded to a power of
#: two rows (or one common size, :func:`common_rows`).
LANES = 4


def sequential_groups(kinds: np.ndarray, threads: int, costs: np.ndarray | None = None
                       ) -> list[np.ndarray]:
    """Agent indices per work item: one kind each, ≈ ``4 × threads`` items in all.

    ``costs`` estimates each agent's work (e.g. its steps in an earlier run; ``None``: all
    equal). Within a kind, the agents are dealt to the kind's items in order of
    decreasing cost, back and forth, so the items have equal sizes (few shapes to
    compile) and similar costs, and an item's agents stay in order of decreasing cost,
    so that the agents side by side in a loop (:data:`LANES`) finish at similar times.
    Items are returned most costly first, so that the last items to start are short ones
    and the threads finish together.
    """
    num_agents = kinds.shape[0]
    costs = np.ones(num_agents) if costs is None else np.asarray(costs, np.float64)
    # Agents per item: a multiple of the loop width, so that no lane is padding.
    target = LANES * max(1, -(-num_agents // (4 * threads * LANES)))
    groups = []
    for kind in np.unique(kinds):
        members = np.flatnonzero(kinds == kind)
        parts = -(-members.size // target)
        ordered = members[np.argsort(-costs[members], kind="stable")]
        deal = np.arange(ordered.size) % (2 * parts)
        deal = np.where(deal < parts, deal, 2 * parts - 1 - deal)  # 0,1,..,p-1,p-1,..,0
        groups += [ordered[deal == k] for k in range(parts)]
    return sorted(groups, key=lambda group: (-costs[group].sum(), -len(group)))


def next_power_of_two(n: int) -> int:
    """The least power of two ≥ ``n`` (1 for ``n`` ≤ 1): the sizes batches and buffers
    are padded to, so that few shapes are compiled."""
    return 1 << max(0, (n - 1).bit_length())


#: Agents whose state (Q, ε(s)) exceeds this many bytes are created in their work items,
#: on the device, instead of on the host first (no host copy of large tables).
HOST_INIT_MAX_BYTES = 1 << 20


def padded_rows(index: np.ndarray, rows: int = 0) -> np.ndarray:
    """A work item's rows, repeated up to a power of two, or to ``rows`` if more (few
    shapes to compile; padding rows never run)."""
    return np.resize(index, max(next_power_of_two(index.size), rows))


def common_rows(groups: list[np.ndarray]) -> int:
    """One padded size for every work item (one program for all: its trace is most of
    what a run pays besides the steps), unless that more than doubles the rows; else 0."""
    size = next_power_of_two(max(group.size for group in groups))
    return size if size * len(groups) <= 2 * sum(group.size for group in groups) else 0


def created_in_items(mdp: TabularMDP, params: AgentParams) -> bool:
    """Whether an agent's tables exceed :data:`HOST_INIT_MAX_BYTES` (see
    :class:`~vdbejax.engine.sequential.SequentialRun`)."""
    return state_bytes(mdp, table_layout(params)) > HOST_INIT_MAX_BYTES
