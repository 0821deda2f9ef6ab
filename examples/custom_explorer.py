"""A user-defined explorer and learner, run beside VDBE-Softmax in one vdbejax grid.

    python examples/custom_explorer.py --seeds 20 --episodes 1000 [--out DIR]

* ``visit_epsilon`` (explorer): ε-greedy whose ε decays with the state's own visits,
  ``ε(s) = ε₀ / sqrt(N(s) + 1)``; it keeps its own per-state visit table N(s).
* ``mellow_q`` (learner): Q-learning whose target replaces the max by Asadi & Littman's
  mellowmax, ``mm_ω(Q(s',·)) = log(mean(exp(ω·Q(s',·)))) / ω`` (→ max as ω → ∞).

Both are plain classes of pure JAX functions on one agent's Q row; vdbejax vmaps them over
every agent and seed and compiles them into the same per-kind native loops as its built-ins.
Import this file (``vdbejax run --plugin examples/custom_explorer.py``) to use them in
any sweep.
"""
from __future__ import annotations

import argparse

import jax
import jax.numpy as jnp

from vdbejax.methods import (
    Explorer,
    Learner,
    LearnerUpdate,
    Table,
    explorer,
    learner,
    select_action,
)
from vdbejax.methods.learners import td_update


@explorer("visit_epsilon", parameter="epsilon0", title="visit-decayed ε-greedy")
class VisitEpsilon(Explorer):
    """ε-greedy with ε(s) = ε₀ / sqrt(N(s) + 1), N(s) the visits to the state."""

    epsilon0: float = 0.5
    num_uniforms = 3  # explore or not, the random action, the greedy tie break

    def tables(self) -> dict[str, Table]:
        return {"visits": Table("state", 0.0)}

    def select(self, q, tables, context, uniforms):
        epsilon = self.epsilon0 / jnp.sqrt(tables["visits"] + 1.0)
        return select_action(q, epsilon, None, uniforms)

    def update(self, tables, action, delta_q, context):
        return {"visits": tables["visits"] + 1.0}


@learner("mellow_q")
class MellowQ(Learner):
    """Q-learning with a mellowmax target of temperature ω."""

    alpha: float = 0.8
    gamma: float = 0.9
    q_init: float = 0.0
    omega: float = 10.0

    def update(self, t):
        mellow = jax.nn.logsumexp(self.omega * t.q_next) - jnp.log(t.q_next.shape[0])
        target = t.reward + t.discount * mellow / self.omega
        new, delta_q = td_update(t.q, target, self.alpha)
        return LearnerUpdate(new, {}, delta_q)


def main(argv: list[str] | None = None) -> int:
    import vdbejax
    from vdbejax.envs.table_cleaning import make_mdp
    from vdbejax.methods import Setting
    from vdbejax.results.analysis import summarize

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=20)
    parser.add_argument("--episodes", type=int, default=1000)
    parser.add_argument("--out", default=None, help="save the result folder here")
    args = parser.parse_args(argv)
    settings = [
        Setting("qlearning", "visit_epsilon", 0.5),
        Setting("qlearning", "visit_epsilon", 1.0),
        Setting("mellow_q", "egreedy", 0.1, {"omega": 20.0}),
        Setting("mellow_q", "visit_epsilon", 0.5),
        Setting("qlearning", "vdbe_softmax", 1.0),
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
