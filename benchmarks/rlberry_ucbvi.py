"""vdbejax's UCBVI beside rlberry-scool's ``UCBVIAgent``: the same task, horizon and bonus.

Two tasks (``--task``). ``riverswim``: RiverSwim (Strehl & Littman 2008; the 6-state form
of Osband, Russo & Van Roy 2013): swimming left always works and pays 0.005 at the left
bank; swimming right moves right with probability 0.35 (0.6 at the right bank, where it
pays 1), stays with 0.6 (0.4 at the bank) and drifts left with 0.05 (at the left bank:
right with 0.4, stays 0.6).
``random``: a random task that no benchmark of vdbejax uses (:func:`random_task`:
S = 8 states, A = 3 actions, each pair with 3 successors of Dirichlet(1) probabilities
and a reward drawn uniformly from [−1, 1], fixed seed), whose reward range (about 2) is
not the default ``r_max`` of 1. Rewards depend on (s, a) only, no state is terminal;
every episode starts in state 0 and lasts H steps. Both agents: γ = 1, horizon H, the
simplified Bernstein bonus ``min(c√(1/n) + v_max_h/n, v_max_h)`` with scale c, greedy
with ties to the first action.

    python -m benchmarks.rlberry_ucbvi --part vdbejax --out DIR      # the project venv
    PEER_PYTHON -m benchmarks.rlberry_ucbvi --part rlberry --out DIR # a venv with rlberry-scool
    python -m benchmarks.rlberry_ucbvi --part compare --out DIR

(``--task``, ``--agents``, ``--episodes``, ``--horizon``, ``--scale``; the same values for
every part.) ``--label NAME`` writes the vdbejax part as ``NAME.json`` (e.g. another
checkout's vdbejax on ``PYTHONPATH``) and ``--against NAME`` compares that file with
rlberry's. The comparison splits the episodes into 5 windows and gives, per window, the
99 % bootstrap interval of the difference of the two mean window returns over agents
(agents resampled within each side); the agents agree in a window where it holds 0.
rlberry runs one agent at a time (its loops are plain Python and numba); vdbejax runs
every agent at once.
"""
from __future__ import annotations

import argparse
import itertools
import json
import time
from pathlib import Path

import numpy as np

S, A = 6, 2


def river_swim() -> tuple[np.ndarray, np.ndarray]:
    """``(R [S, A], P [S, A, S])``; action 0 = left, 1 = right: the task suite's model
    (``vdbejax.envs.suite.river_swim``), read from its file where JAX is missing (rlberry's
    venv: importing the package ``vdbejax.envs`` imports JAX; the model needs numpy only)."""
    try:
        from vdbejax.envs.suite.river_swim import normalised_river_swim_model
    except ImportError:
        import importlib.util

        path = Path(__file__).resolve().parents[1] / "vdbejax/envs/suite/river_swim.py"
        spec = importlib.util.spec_from_file_location("_suite_river_swim", path)
        assert spec is not None and spec.loader is not None
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
        normalised_river_swim_model = module.normalised_river_swim_model
    return normalised_river_swim_model(S)


def random_task(seed: int = 47) -> tuple[np.ndarray, np.ndarray]:
    """``(R [S, A], P [S, A, S])`` of the ``random`` task (8 states, 3 actions; see the
    module docstring)."""
    rng = np.random.default_rng(seed)
    states, actions, successors = 8, 3, 3
    P = np.zeros((states, actions, states))
    for s in range(states):
        for a in range(actions):
            reached = rng.choice(states, successors, replace=False)
            P[s, a, reached] = rng.dirichlet(np.ones(successors))
    P /= P.sum(axis=-1, keepdims=True)  # rows sum to 1 within rlberry's 1e-15 check
    return rng.uniform(-1.0, 1.0, (states, actions)), P


def task(name: str) -> tuple[np.ndarray, np.ndarray]:
    """The ``--task``'s ``(R, P)``."""
    return river_swim() if name == "riverswim" else random_task()


def run_vdbejax(args: argparse.Namespace) -> dict:
    import vdbejax
    from vdbejax.envs.tabular import make_tabular_mdp
    from vdbejax.methods.agents import AgentOptions, Setting

    R, P = task(args.task)
    S, A = R.shape
    nxt = np.broadcast_to(np.arange(S), (S, A, S)).astype(np.int32)
    rewards = np.broadcast_to(R[..., None], (S, A, S)).astype(np.float32)
    start = np.eye(S, dtype=np.float32)[0]
    mdp = make_tabular_mdp(nxt, rewards, np.zeros((S, A, S), bool), start, P.astype(np.float32),
                           max_steps=args.horizon, name=args.task)
    setting = Setting("ucbvi", "greedy", None, {"gamma": 1.0, "horizon": args.horizon,
                                                "bonus_scale": args.scale,
                                                "convention": "rlberry"})
    options = AgentOptions(tie_break="first")
    # the same call once before the clock starts: compiling is not the work compared
    vdbejax.run_grid(mdp, [setting], num_seeds=args.agents, num_episodes=args.episodes,
                     options=options)
    started = time.perf_counter()
    grid = vdbejax.run_grid(mdp, [setting], num_seeds=args.agents, num_episodes=args.episodes,
                            options=options)
    seconds = time.perf_counter() - started
    return {"returns": grid.returns[0].astype(float).tolist(), "seconds": seconds}


def run_rlberry(args: argparse.Namespace) -> dict:
    from rlberry.envs import FiniteMDP
    from rlberry_scool.agents import UCBVIAgent

    R, P = task(args.task)
    returns = []
    started = time.perf_counter()
    for seed in range(args.agents):
        env = FiniteMDP(R, P, initial_state_distribution=0)
        agent = UCBVIAgent(env, gamma=1.0, horizon=args.horizon, bonus_scale_factor=args.scale,
                           bonus_type="simplified_bernstein", seeder=seed)
        returns.append([float(agent._run_episode()) for _ in range(args.episodes)])
    return {"returns": returns, "seconds": time.perf_counter() - started}


def windows(episodes: int) -> list[tuple[int, int]]:
    """The 5 windows ``[lo, hi)`` of episodes the comparison splits a run into."""
    edges = [round(episodes * k / 5) for k in range(6)]
    return list(itertools.pairwise(edges))


def difference_interval(x: np.ndarray, y: np.ndarray, rng: np.random.Generator,
                        resamples: int = 10_000) -> tuple[float, float]:
    """The 99 % bootstrap interval of ``mean(x) − mean(y)`` (each side resampled)."""
    xs = rng.choice(x, (resamples, x.size)).mean(axis=1)
    ys = rng.choice(y, (resamples, y.size)).mean(axis=1)
    low, high = np.quantile(xs - ys, [0.005, 0.995])
    return float(low), float(high)


def compare(out: Path, against: str = "vdbejax") -> str:
    ours = json.loads((out / f"{against}.json").read_text())
    theirs = json.loads((out / "rlberry.json").read_text())
    a, b = np.asarray(ours["returns"]), np.asarray(theirs["returns"])
    episodes = a.shape[1]
    lines = [f"| episodes | {against} mean return | rlberry mean return | difference |"
             " 99 % interval of the difference | holds 0 |",
             "| --- | --- | --- | --- | --- | --- |"]
    rng = np.random.default_rng(0)
    agree = 0
    for lo, hi in windows(episodes):
        x, y = a[:, lo:hi].mean(axis=1), b[:, lo:hi].mean(axis=1)
        low, high = difference_interval(x, y, rng)
        holds = low <= 0.0 <= high
        agree += int(holds)
        lines.append(f"| {lo + 1}–{hi} | {x.mean():.3f} | {y.mean():.3f} |"
                     f" {x.mean() - y.mean():+.3f} | [{low:+.3f}, {high:+.3f}] |"
                     f" {'yes' if holds else 'no'} |")
    lines.append("")
    lines.append(f"Windows that agree: {agree}/5. Time for {a.shape[0]} agents"
                 f" × {episodes} episodes: {against} {ours['seconds']:.2f} s, rlberry"
                 f" {theirs['seconds']:.2f} s: rlberry / {against} ="
                 f" {theirs['seconds'] / ours['seconds']:.3g}×.")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--part", choices=("vdbejax", "rlberry", "compare"), required=True)
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--task", choices=("riverswim", "random"), default="riverswim")
    parser.add_argument("--label", default="vdbejax",
                        help="the vdbejax part's file name (without .json)")
    parser.add_argument("--against", default="vdbejax",
                        help="the file (without .json) compare sets beside rlberry's")
    parser.add_argument("--agents", type=int, default=20)
    parser.add_argument("--episodes", type=int, default=500)
    parser.add_argument("--horizon", type=int, default=20)
    parser.add_argument("--scale", type=float, default=0.1)
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    if args.part == "compare":
        print(compare(args.out, args.against))
        return
    result = run_vdbejax(args) if args.part == "vdbejax" else run_rlberry(args)
    name = args.label if args.part == "vdbejax" else "rlberry"
    (args.out / f"{name}.json").write_text(json.dumps(result))
    print(f"{name}: {result['seconds']:.2f} s")


if __name__ == "__main__":
    main()
