"""PSRL's two priors side by side on RiverSwim: Osband, Russo & Van Roy (2013)'s Dirichlet
over the successor states (``terminal_outcome="task"``, the default: RiverSwim has no
terminal outcome) against vdbejax's earlier prior, which adds a "terminal" outcome
(``terminal_outcome="always"``).

    python -m benchmarks.psrl_prior [--task osband|suite] [--agents N] [--episodes E]

``osband``: the 6-state RiverSwim of Osband et al. (rewards 0.005 and 1;
``benchmarks/rlberry_ucbvi.py``'s model), H = 20. ``suite``: the task suite's
``riverswim`` (Strehl & Littman's rewards 5 and 10,000), its own step limit. γ = 1,
horizon H, the same seeds for both priors. Prints, per window of a fifth of the episodes,
the mean returns over agents and the 99 % bootstrap interval of their difference
(agents resampled on each side), then each prior's cumulative realized regret (the best
expected return less each episode's return, summed) with the same interval.
"""
from __future__ import annotations

import argparse
import time

import numpy as np


def make_task(name: str):  # type: ignore[no-untyped-def]
    from vdbejax.envs.tabular import make_tabular_mdp
    from vdbejax.studies.task_names import make_task as suite_task

    if name == "suite":
        return suite_task("riverswim")
    from benchmarks.rlberry_ucbvi import river_swim

    R, P = river_swim()
    S, A = R.shape
    nxt = np.broadcast_to(np.arange(S), (S, A, S)).astype(np.int32)
    rewards = np.broadcast_to(R[..., None], (S, A, S)).astype(np.float32)
    return make_tabular_mdp(nxt, rewards, np.zeros((S, A, S), bool),
                            np.eye(S, dtype=np.float32)[0], P.astype(np.float32),
                            max_steps=20, name="riverswim-osband")


def main() -> None:
    import vdbejax
    from benchmarks.rlberry_ucbvi import difference_interval, windows
    from vdbejax.methods.agents import Setting

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--task", choices=("osband", "suite"), default="osband")
    parser.add_argument("--agents", type=int, default=100)
    parser.add_argument("--episodes", type=int, default=200)
    args = parser.parse_args()
    mdp = make_task(args.task)
    H = int(mdp.max_steps)
    settings = [Setting("psrl", "greedy", None, {"horizon": H, "gamma": 1.0,
                                                 "terminal_outcome": outcome})
                for outcome in ("task", "always")]
    started = time.perf_counter()
    grid = vdbejax.run_grid(mdp, settings, num_seeds=args.agents, num_episodes=args.episodes)
    print(f"{mdp.name}: S = {mdp.num_states}, H = {H}, {args.agents} agents ×"
          f" {args.episodes} episodes, {time.perf_counter() - started:.1f} s")
    print("| episodes | task (Osband et al.) | always (earlier) | difference |"
          " 99 % interval |\n| --- | --- | --- | --- | --- |")
    rng = np.random.default_rng(0)
    for lo, hi in windows(args.episodes):
        x, y = grid.returns[0][:, lo:hi].mean(axis=1), grid.returns[1][:, lo:hi].mean(axis=1)
        low, high = difference_interval(x, y, rng)
        print(f"| {lo + 1}–{hi} | {x.mean():.3f} | {y.mean():.3f} | {x.mean() - y.mean():+.3f} |"
              f" [{low:+.3f}, {high:+.3f}] |")
    from vdbejax.envs.solvers import best_return

    best = best_return(mdp)  # realized regret: the best expected return less each episode's
    x, y = ((best - grid.returns[i]).sum(axis=1) for i in (0, 1))
    low, high = difference_interval(x, y, rng)
    print(f"\nCumulative realized regret over {args.episodes} episodes (best return {best:.4g}"
          f" an episode): task {x.mean():.1f}, always {y.mean():.1f}, difference"
          f" {x.mean() - y.mean():+.1f}, 99 % interval [{low:+.1f}, {high:+.1f}]")


if __name__ == "__main__":
    main()
