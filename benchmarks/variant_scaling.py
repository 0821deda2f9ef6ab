"""Task-size scaling: generated table-cleaning variants, their size, run time and memory.

Usage::

    python -m benchmarks.variant_scaling --variants 2x1 4x2 6x3 8x3 9x3 --out benchmarks/VARIANTS.md

For each variant ``n x k``, in a fresh subprocess (so that the peak memory is the
variant's own): compile it (reachable states only), solve it exactly (best return,
shortest solution), then train a small grid with ``run_grid`` (4 settings × ``--seeds``
seeds × ``--episodes`` episodes). Throughput = real agent-steps / (grid time − time spent
getting the engine's programs). Writes a markdown table and a plot of throughput and peak
memory against the number of states (``variant_scaling.png`` beside ``--out``); with
``--out -`` only the JSON lines are printed.
"""
from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import time
from pathlib import Path

SETTINGS = [
    ("qlearning", "egreedy", 0.1),
    ("qlearning", "vdbe_softmax", 1.0),
    ("sarsa", "softmax", 0.001),
    ("sarsa", "vdbe", 1.0),
]
ROOT = Path(__file__).resolve().parents[1]


def peak_rss_gib() -> float:
    """Peak resident memory of this process so far (GiB; Linux reports KiB)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20


def measure(n: int, k: int, seeds: int, episodes: int, max_steps: int) -> dict:
    """Compile, solve and run one variant (in this process); returns the measurements."""
    from vdbejax import engine
    from vdbejax.envs import solvers
    from vdbejax.envs.table_cleaning import make_variant, make_variant_mdp
    from vdbejax.methods.agents import Setting
    from vdbejax.runs import run_grid

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
        settings = [Setting(*s) for s in SETTINGS]
        programs_before = engine.compile_seconds()
        started = time.perf_counter()
        grid = run_grid(mdp, settings, num_seeds=seeds, num_episodes=episodes,
                        chunk_episodes=min(100, episodes))
        grid_s = time.perf_counter() - started
        programs_s = engine.compile_seconds() - programs_before
        agent_steps = int(grid.lengths.sum())
        last = grid.returns[:, :, -max(1, episodes // 10):].mean(axis=(1, 2))
        row.update(agents=len(settings) * seeds, episodes=episodes, grid_s=round(grid_s, 2),
                   programs_s=round(programs_s, 2), agent_steps=agent_steps,
                   steps_per_s=agent_steps / max(grid_s - programs_s, 1e-9),
                   final_mean_return={s.label: round(float(v), 3) for s, v in zip(settings, last)})
    row["peak_rss_gib"] = round(peak_rss_gib(), 2)
    return row


def _table(rows: list[dict]) -> list[str]:
    header = ("| n×k | codes | reachable states | actions | Q-table / agent | best return | "
              "shortest solution | compile | solve | grid (programs) | agent steps | "
              "M steps/s | peak |")
    lines = [header,
             "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    for r in rows:
        low, high = r["shortest_solution"]
        grid = (f"{r['grid_s']:.1f} s ({r['programs_s']:.1f} s)" if "grid_s" in r else "–")
        lines.append(
            f"| {r['variant'].replace('x', '×')} | {r['codes']:,} | {r['states']:,} | "
            f"{r['actions']} | {r['q_table_mib']:.2f} MiB | {r['best_return']:.2f} | "
            f"{low if low == high else f'{low}–{high}'} | {r['compile_s']:.1f} s | "
            f"{r['solve_s']:.1f} s | {grid} | {r.get('agent_steps', 0):,} | "
            f"{r.get('steps_per_s', 0) / 1e6:.3g} | {r['peak_rss_gib']:.1f} GiB |")
    return lines


def _plot(rows: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = [r for r in rows if "steps_per_s" in r]
    states = [r["states"] for r in rows]
    fig, (left, right) = plt.subplots(1, 2, figsize=(10, 4))
    left.loglog(states, [r["steps_per_s"] for r in rows], "o-")
    left.set_ylabel("real agent-steps / s (programs excluded)")
    left.set_title("throughput")
    right.loglog(states, [r["peak_rss_gib"] for r in rows], "o-", color="C1")
    right.set_ylabel("peak RSS (GiB)")
    right.set_title("memory")
    for axis in (left, right):
        axis.set_xlabel("reachable states")
        axis.grid(True, which="both", alpha=0.3)
    for r in rows:
        left.annotate(r["variant"], (r["states"], r["steps_per_s"]), fontsize=8)
        right.annotate(r["variant"], (r["states"], r["peak_rss_gib"]), fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=120)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--variants", nargs="+", default=["2x1", "4x2", "6x3"])
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--episodes", type=int, default=200)
    parser.add_argument("--max-steps", type=int, default=100)
    parser.add_argument("--out", default=str(ROOT / "benchmarks" / "VARIANTS.md"),
                        help="markdown report ('-': JSON lines only)")
    parser.add_argument("--worker", action="store_true", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.worker:
        (variant,) = args.variants
        n, k = (int(x) for x in variant.split("x"))
        print(json.dumps(measure(n, k, args.seeds, args.episodes, args.max_steps)), flush=True)
        return 0
    rows = []
    for variant in args.variants:
        command = [sys.executable, "-m", "benchmarks.variant_scaling", "--worker",
                   "--variants", variant, "--seeds", str(args.seeds),
                   "--episodes", str(args.episodes), "--max-steps", str(args.max_steps)]
        done = subprocess.run(command, cwd=ROOT, capture_output=True, text=True, check=False)
        if done.returncode != 0:
            print(f"{variant}: failed ({done.returncode}): {done.stderr.strip()[-300:]}",
                  file=sys.stderr)
            continue
        rows.append(json.loads(done.stdout.strip().splitlines()[-1]))
        print(json.dumps(rows[-1]), flush=True)
    if args.out != "-" and rows:
        from benchmarks.compare import _machine

        out = Path(args.out)
        png = out.with_name("variant_scaling.png")
        _plot(rows, png)
        shown = " ".join(sys.argv[1:]) if argv is None else " ".join(argv)
        lines = ["# Task-size scaling: generated table-cleaning variants", "", *_machine(),
                 f"- Command: `python -m benchmarks.variant_scaling {shown}`.",
                 "",
                 (f"Each variant in a fresh process: *compile* = `make_variant_mdp` (reachable "
                  f"states only), *solve* = `best_return` + `steps_to_goal`, *grid* = `run_grid` "
                  f"with {len(SETTINGS)} settings × {args.seeds} seeds × {args.episodes} "
                  "episodes (in brackets: the part spent getting the engine's programs, "
                  "compiled or loaded from the caches), *M steps/s* = real agent-steps / (grid "
                  "− programs), *peak* = the process's peak resident memory."), "",
                 *_table(rows), "", f"![throughput and memory against states]({png.name})", ""]
        out.write_text("\n".join(lines))
        print(f"wrote {out} and {png}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
