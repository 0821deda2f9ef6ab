"""Time the exploration canon on the paper's task (issue "The exploration canon", point 4).

For each method: one setting × 20 agents × 1000 episodes through ``run_grid`` (the first
call compiles; the median of the next ``--repeats`` calls is reported), its real steps,
µs per step, and its final return; then the planning cost: value-iteration sweeps per
second per agent of the optimistic backup on a model of the paper task's size.

    python -m benchmarks.canon [--repeats 3] [--episodes 1000] [--seeds 20]
"""
from __future__ import annotations

import argparse
import statistics
import time

import jax
import jax.numpy as jnp
import numpy as np

import vdbejax
from vdbejax import run_grid
from vdbejax.engine import programs
from vdbejax.envs.table_cleaning import make_mdp
from vdbejax.methods.agents import Setting
from vdbejax.methods.model import Model
from vdbejax.methods.model_based import optimistic_backup

METHODS = [
    Setting("qlearning", "egreedy", 0.1),
    Setting("rmax", "greedy"),
    Setting("mbie_eb", "greedy"),
    Setting("dyna_q", "egreedy", 0.1),
    Setting("dyna_q_plus", "egreedy", 0.1),
    Setting("sarsa_lambda", "egreedy", 0.1),
    Setting("q_lambda", "egreedy", 0.1),
    Setting("ucbvi", "greedy", None, {"gamma": 1.0, "bonus_scale": 0.1}),
    Setting("ucbvi", "greedy", None, {"gamma": 1.0, "bonus": "hoeffding",
                                      "bonus_scale": 0.001}),
    Setting("ucb_h", "greedy", None, {"gamma": 1.0, "bonus_scale": 0.001}),
    Setting("delayed_q", "greedy"),
    Setting("psrl", "greedy", None, {"gamma": 1.0}),
]


def time_methods(seeds: int, episodes: int, repeats: int) -> list[dict]:
    mdp, rows = make_mdp(), []
    for setting in METHODS:
        before = programs.compile_seconds()
        started = time.perf_counter()
        grid = run_grid(mdp, [setting], num_seeds=seeds, num_episodes=episodes)
        first = time.perf_counter() - started
        compiled = programs.compile_seconds() - before
        walls = []
        for _ in range(repeats):
            started = time.perf_counter()
            grid = run_grid(mdp, [setting], num_seeds=seeds, num_episodes=episodes)
            walls.append(time.perf_counter() - started)
        wall = statistics.median(walls)
        steps = int(grid.lengths.sum())
        rows.append({"setting": setting.label, "first": first, "programs": compiled,
                     "wall": wall, "steps": steps, "us_per_step": 1e6 * wall / steps,
                     "final": float(grid.returns[0, :, -100:].mean())})
        print(f"| {setting.label} | {first:.2f} | {wall:.2f} | {steps:,} | "
              f"{1e6 * wall / steps:.2f} | {rows[-1]['final']:.3f} |", flush=True)
    return rows


def time_sweeps(agents: int = 20, sweeps: int = 200) -> float:
    """Sweeps per second per agent of the optimistic backup on the paper task's shape."""
    mdp = make_mdp()
    S, A = mdp.num_states, mdp.num_actions
    rng = np.random.default_rng(0)
    visits = jnp.asarray(rng.integers(1, 5, (agents, S, A)), jnp.float32)
    model = Model(visits, visits * 0.1, visits * 0.01, jnp.zeros_like(visits),
                  jnp.asarray(rng.integers(0, S, (agents, S, A, 1)), jnp.float32),
                  visits[..., None])

    @jax.jit
    def run(model: Model, q: jax.Array) -> jax.Array:
        def one(model: Model, q: jax.Array) -> jax.Array:
            return jax.lax.fori_loop(0, sweeps, lambda _, q: optimistic_backup(
                model, q, 0.9, jnp.zeros_like(q), model.visits > 0, 10.0), q)
        return jax.vmap(one)(model, q)

    q = jnp.zeros((agents, S, A), jnp.float32)
    run(model, q).block_until_ready()
    started = time.perf_counter()
    run(model, q).block_until_ready()
    return sweeps * agents / (time.perf_counter() - started) / agents


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--episodes", type=int, default=1000)
    parser.add_argument("--seeds", type=int, default=20)
    parser.add_argument("--only", default="", help="comma-separated learner names to time")
    args = parser.parse_args()
    if args.only:
        METHODS[:] = [s for s in METHODS if s.learner in args.only.split(",")]
    print(f"vdbejax {vdbejax.__version__}, jax {jax.__version__}, "
          f"{args.seeds} agents × {args.episodes} episodes per setting, paper task")
    print("| setting | first call s | warm s (median) | steps | µs/step | final return |")
    print("| --- | --- | --- | --- | --- | --- |")
    time_methods(args.seeds, args.episodes, args.repeats)
    print(f"optimistic backup: {time_sweeps():,.0f} sweeps/s per agent "
          "(S = 108, A = 7, K = 1; 20 agents vmapped)")


if __name__ == "__main__":
    main()
