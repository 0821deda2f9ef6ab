"""A user-written model-based learner, run beside R-max, MBIE-EB and Q-learning in one grid.

    python examples/model_based_plugin.py --seeds 20 --episodes 300 [--out DIR]

``ucb_vi`` (learner): count-based optimism with a bonus that shrinks with the agent's
own experience, ``Q = r̂ + β·√(ln(t + 1)/n(s, a)) + γ P̂ max Q`` (unvisited pairs worth
``r_max/(1 − γ)``), re-planned every ``plan_every`` iterations (``plan_at = "every"``).
It uses the engine's count model (``uses_model``) and its planning hook, and the
library's pieces: the model's ``expected`` values and ``value_iteration``. Import this
file (``vdbejax run --plugin examples/model_based_plugin.py``) to use it in any sweep.
"""
from __future__ import annotations

import argparse

import jax.numpy as jnp

from vdbejax.methods import Learner, LearnerUpdate, learner
from vdbejax.methods.model import bellman_backup, greedy_values, value_iteration


@learner("ucb_vi", title="UCB value iteration")
class UCBValueIteration(Learner):
    """Optimistic value iteration with a log-time count bonus, planned every k steps."""

    gamma: float = 0.9
    beta: float = 0.05
    r_max: float = 1.0
    plan_every: float = 10.0
    uses_model = True
    plan_at = "every"

    def initial_q(self, key, num_states, num_actions):
        return jnp.full((num_states, num_actions), self.r_max / (1.0 - self.gamma))

    def update(self, t):  # Q comes from planning alone
        return LearnerUpdate(t.q, {}, jnp.zeros_like(t.q))

    def plan(self, q, tables, model, context, uniforms):
        steps = jnp.sum(model.visits)
        visited = model.visits > 0
        bonus = self.beta * jnp.sqrt(jnp.log(steps + 1.0) / jnp.maximum(model.visits, 1.0))
        optimistic = self.r_max / (1.0 - self.gamma)

        def backup(values):
            future = model.expected(greedy_values(values))
            backed = bellman_backup(model.mean_reward() + bonus, self.gamma, future)
            return jnp.where(visited, backed, optimistic)

        return value_iteration(backup, q, tolerance=1e-4, max_sweeps=500), {}


def main(argv: list[str] | None = None) -> int:
    import vdbejax
    from vdbejax.envs.table_cleaning import make_mdp
    from vdbejax.methods import Setting
    from vdbejax.results.analysis import summarize

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=20)
    parser.add_argument("--episodes", type=int, default=300)
    parser.add_argument("--out", default=None, help="save the result folder here")
    args = parser.parse_args(argv)
    settings = [
        Setting("ucb_vi", "greedy", None, {"beta": 0.05}),
        Setting("ucb_vi", "greedy", None, {"beta": 0.05, "plan_every": 50.0}),
        Setting("rmax", "greedy"),
        Setting("mbie_eb", "greedy"),
        Setting("qlearning", "egreedy", 0.1),
    ]
    grid = vdbejax.run_grid(make_mdp(), settings, num_seeds=args.seeds,
                            num_episodes=args.episodes)
    for setting, row in zip(grid.settings, summarize(grid)):
        print(f"{setting.label}: final return {row['final_return']:.3f}"
              f" [{row['final_ci_low']:.3f}, {row['final_ci_high']:.3f}]")
    if args.out:
        grid.save(args.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
