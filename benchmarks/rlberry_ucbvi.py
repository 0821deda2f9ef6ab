"""vdbejax's UCBVI beside rlberry-scool's ``UCBVIAgent``: the same task, horizon and bonus.

The task is RiverSwim (Strehl & Littman 2008; the 6-state form of Osband, Russo & Van Roy
2013): swimming left always works and pays 0.005 at the left bank; swimming right moves
right with probability 0.35 (0.6 at the right bank, where it pays 1), stays with 0.6 (0.4
at the bank) and drifts left with 0.05 (at the left bank: right with 0.4, stays 0.6).
Rewards depend on (s, a) only, no state is terminal; every episode starts at the left
bank and lasts H steps. Both agents: γ = 1, horizon H, the simplified Bernstein bonus
``min(c√(1/n) + v_max_h/n, v_max_h)`` with scale c, greedy with ties to the first action.

    python -m benchmarks.rlberry_ucbvi --part vdbejax --out DIR      # the project venv
    PEER_PYTHON -m benchmarks.rlberry_ucbvi --part rlberry --out DIR # a venv with rlberry-scool
    python -m benchmarks.rlberry_ucbvi --part compare --out DIR

(``--agents``, ``--episodes``, ``--horizon``, ``--scale``.) rlberry runs one agent at a
time (its loops are plain Python and numba); vdbejax runs every agent at once.
"""
from __future__ import annotations

import argparse
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


def run_vdbejax(args: argparse.Namespace) -> dict:
    import vdbejax
    from vdbejax.envs.tabular import make_tabular_mdp
    from vdbejax.methods.agents import AgentOptions, Setting

    R, P = river_swim()
    nxt = np.broadcast_to(np.arange(S), (S, A, S)).astype(np.int32)
    rewards = np.broadcast_to(R[..., None], (S, A, S)).astype(np.float32)
    start = np.eye(S, dtype=np.float32)[0]
    mdp = make_tabular_mdp(nxt, rewards, np.zeros((S, A, S), bool), start, P.astype(np.float32),
                           max_steps=args.horizon, name="riverswim")
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

    R, P = river_swim()
    returns = []
    started = time.perf_counter()
    for seed in range(args.agents):
        env = FiniteMDP(R, P, initial_state_distribution=0)
        agent = UCBVIAgent(env, gamma=1.0, horizon=args.horizon, bonus_scale_factor=args.scale,
                           bonus_type="simplified_bernstein", seeder=seed)
        returns.append([float(agent._run_episode()) for _ in range(args.episodes)])
    return {"returns": returns, "seconds": time.perf_counter() - started}


def compare(out: Path) -> str:
    ours = json.loads((out / "vdbejax.json").read_text())
    theirs = json.loads((out / "rlberry.json").read_text())
    a, b = np.asarray(ours["returns"]), np.asarray(theirs["returns"])
    episodes = a.shape[1]
    lines = ["| episodes | vdbejax mean return | rlberry mean return | difference |"
             " 99 % interval of the difference under equal means |",
             "| --- | --- | --- | --- | --- |"]
    rng = np.random.default_rng(0)
    agree = 0
    windows = [(lo, min(lo + max(episodes // 5, 1), episodes)) for lo in
               range(0, episodes, max(episodes // 5, 1))]
    for lo, hi in windows:
        x, y = a[:, lo:hi].mean(axis=1), b[:, lo:hi].mean(axis=1)
        pooled = np.concatenate([x, y])
        diffs = []
        for _ in range(4000):
            sample = rng.choice(pooled, pooled.size)
            diffs.append(sample[:x.size].mean() - sample[x.size:].mean())
        low, high = np.quantile(diffs, [0.005, 0.995])
        difference = x.mean() - y.mean()
        agree += int(low <= difference <= high)
        lines.append(f"| {lo + 1}–{hi} | {x.mean():.3f} | {y.mean():.3f} | {difference:+.3f} |"
                     f" [{low:+.3f}, {high:+.3f}] |")
    lines.append("")
    lines.append(f"Windows that agree: {agree}/{len(windows)}. Time for {a.shape[0]} agents ×"
                 f" {episodes} episodes: vdbejax {ours['seconds']:.2f} s, rlberry"
                 f" {theirs['seconds']:.2f} s: rlberry / vdbejax ="
                 f" {theirs['seconds'] / ours['seconds']:.0f}×.")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--part", choices=("vdbejax", "rlberry", "compare"), required=True)
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--agents", type=int, default=20)
    parser.add_argument("--episodes", type=int, default=500)
    parser.add_argument("--horizon", type=int, default=20)
    parser.add_argument("--scale", type=float, default=0.1)
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    if args.part == "compare":
        print(compare(args.out))
        return
    result = run_vdbejax(args) if args.part == "vdbejax" else run_rlberry(args)
    (args.out / f"{args.part}.json").write_text(json.dumps(result))
    print(f"{args.part}: {result['seconds']:.2f} s")


if __name__ == "__main__":
    main()
