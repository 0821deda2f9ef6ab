"""Size, best return and grid run time of generated table-cleaning variants.

Usage::

    python -m benchmarks.variant_scaling --variants 2x1 4x2 6x3 8x3 --seeds 5 --episodes 200

For each variant ``n x k``: compile (reachable states only), solve exactly (best return,
shortest solution), then run a small grid with ``run_grid`` and report wall time and the
process's peak resident memory. One JSON line per variant on stdout.
"""
from __future__ import annotations

import argparse
import json
import resource
import time

from vdbejax import solvers
from vdbejax.agents import Setting
from vdbejax.envs.table_cleaning import make_variant, make_variant_mdp
from vdbejax.experiment import run_grid

SETTINGS = [
    Setting("qlearning", "egreedy", 0.1),
    Setting("qlearning", "vdbe_softmax", 1.0),
    Setting("sarsa", "softmax", 0.001),
    Setting("sarsa", "vdbe", 1.0),
]


def peak_rss_gib() -> float:
    """Peak resident memory of this process so far (GiB; Linux reports KiB)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20


def measure(n: int, k: int, seeds: int, episodes: int, max_steps: int) -> dict:
    """Compile, solve and run one variant; returns the measurements."""
    started = time.perf_counter()
    mdp = make_variant_mdp(n, k, max_steps=max_steps)
    compile_s = time.perf_counter() - started
    started = time.perf_counter()
    best = solvers.best_return(mdp)
    steps = solvers.steps_to_goal(mdp)[solvers.start_states(mdp)]
    solve_s = time.perf_counter() - started
    row = dict(variant=f"{n}x{k}", codes=make_variant(n, k).num_codes(),
               states=mdp.num_states, actions=mdp.num_actions,
               q_table_mib=mdp.num_states * mdp.num_actions * 4 / 2**20,
               best_return=round(best, 6), shortest_solution=[int(steps.min()), int(steps.max())],
               compile_s=round(compile_s, 2), solve_s=round(solve_s, 2))
    if episodes:
        started = time.perf_counter()
        grid = run_grid(mdp, SETTINGS, num_seeds=seeds, num_episodes=episodes,
                        chunk_episodes=episodes)
        last = grid.returns[:, :, -max(1, episodes // 10):].mean(axis=(1, 2))
        row.update(agents=len(SETTINGS) * seeds, episodes=episodes,
                   grid_s=round(time.perf_counter() - started, 2),
                   agent_steps=int(grid.lengths.sum()),
                   final_mean_return={s.label: round(float(v), 3) for s, v in zip(SETTINGS, last)})
    row["peak_rss_gib"] = round(peak_rss_gib(), 2)
    return row


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--variants", nargs="+", default=["2x1", "4x2", "6x3"])
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--episodes", type=int, default=200)
    parser.add_argument("--max-steps", type=int, default=100)
    args = parser.parse_args()
    for variant in args.variants:
        n, k = (int(x) for x in variant.split("x"))
        print(json.dumps(measure(n, k, args.seeds, args.episodes, args.max_steps)), flush=True)


if __name__ == "__main__":
    main()
