"""Cost of one agent step of the engine, per kind of agent, on one or more threads.

Usage::

    python -m benchmarks.step_cost --seeds 5 --threads 1

Runs the paper's settings (46 × ``--seeds`` agents × ``--episodes`` episodes) through
``run_agents`` once to compile, then times a second identical run: nanoseconds per real
environment step and thread, for the whole grid and for each learner × explorer. One
JSON line per row on stdout. The rows ``*/user_egreedy`` run a plug-in defined here,
outside the package, that computes what the built-in ε-greedy computes: a user's explorer
of the same cost runs at the built-in's speed when the two rows agree.
"""
from __future__ import annotations

import argparse
import json
import time


def step_cost(settings: list, seeds: int, episodes: int, threads: int, strategy: str) -> dict:
    """Time the second of two identical runs of ``settings``; ns per step per thread."""
    from vdbejax import engine
    from vdbejax.envs.table_cleaning import make_mdp
    from vdbejax.runs import grid_agents

    mdp = make_mdp()
    params, keys = grid_agents(settings, seeds)

    def run():
        return engine.run_agents(mdp, params, keys, episodes,
                                 engine.EngineOptions(threads=threads, chunk_episodes=episodes,
                                                      strategy=strategy))

    run()
    started = time.perf_counter()
    result = run()
    seconds = time.perf_counter() - started
    steps = int(result.lengths.sum())
    return {"agents": len(keys), "steps": steps, "seconds": round(seconds, 3),
            "ns_per_step_per_thread": round(seconds * threads / steps * 1e9, 1),
            "lane_efficiency": round(result.iterations / max(result.lane_iterations, 1), 3),
            "strategy": result.strategy}


def _register_user_egreedy() -> None:
    """A user-defined copy of ε-greedy (same arithmetic as the built-in)."""
    from vdbejax._pytree import static_field
    from vdbejax.methods import Explorer, explorer, select_action

    @explorer("user_egreedy", parameter="epsilon")
    class UserEpsilonGreedy(Explorer):
        epsilon: float = 0.1
        tie_break: str = static_field("random")

        def select(self, q, tables, context, uniforms):
            return select_action(q, self.epsilon, None, uniforms, self.tie_break)


def main(argv: list[str] | None = None) -> int:
    from vdbejax.methods.agents import Setting, paper_settings

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--episodes", type=int, default=1000)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--strategy", default="auto", choices=["auto", "sequential", "lockstep"])
    args = parser.parse_args(argv)
    settings = paper_settings()
    groups = {"all": settings}
    for setting in settings:
        groups.setdefault(f"{setting.learner}/{setting.explorer}", []).append(setting)
    _register_user_egreedy()
    for learner in ("qlearning", "sarsa"):
        mine = [Setting(s.learner, "user_egreedy", s.param) for s in groups[f"{learner}/egreedy"]]
        groups[f"{learner}/user_egreedy"] = mine
    for name, members in groups.items():
        row = step_cost(members, args.seeds, args.episodes, args.threads, args.strategy)
        print(json.dumps({"settings": name, **row}), flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
