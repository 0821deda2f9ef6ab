"""Accelerator benchmark: the full paper grid and an agent-count sweep on one device.

    python -m benchmarks.gpu --out benchmarks/RESULTS.md          # on the GPU machine
    python -m benchmarks.gpu --out /tmp/gpu.md --quick            # a smoke test anywhere

For each run it prints and records the wall time warm (the same call run first, its wall
with compiling the *cold* time), agent-steps per second and the device's peak memory
(``memory_stats()['peak_bytes_in_use']`` where the backend reports it, else the host's peak
RSS). The sweep multiplies the paper grid's seeds (46 settings × seeds agents) until the
next size would not fit the device (:func:`vdbejax.runs.batching.check_run_size` and the device's
free memory) or ``--max-agents``.

The paper grid's results are then checked against the CPU's: the same call in a
subprocess on the CPU backend (``JAX_PLATFORMS=cpu``), and per setting the bootstrap test
of ``benchmarks.compare.agreement`` on the agents' mean return over the first 300 and the
last 100 episodes (results on an accelerator agree statistically with the CPU's, not to
the bit); the agents whose returns are bit-identical are counted too.

The result is written as the section ``## GPU (benchmarks.gpu)`` of ``--out``: replaced if
present, else appended after the hand-written analysis, which ``benchmarks.compare`` keeps
when it rewrites the file. Nothing here changes what vdbejax computes: the same engine with
its default strategy for the backend (lockstep on accelerators).
"""
from __future__ import annotations

import argparse
import datetime
import os
import platform
import resource
import subprocess
import sys
import tempfile
import textwrap
import time
from pathlib import Path

import numpy as np

HEADING = "## GPU (benchmarks.gpu)"


def _device_summary() -> tuple[str, dict | None]:
    import jax

    device = jax.devices()[0]
    try:
        stats = device.memory_stats()
    except Exception:  # CPU backends raise or return None
        stats = None
    return f"{device.platform}: {device.device_kind} ({len(jax.devices())} device(s))", stats


def _peak_bytes() -> tuple[int, str]:
    """Peak device memory in bytes and where it was read."""
    _, stats = _device_summary()
    if stats and "peak_bytes_in_use" in stats:
        return int(stats["peak_bytes_in_use"]), "device peak"
    return int(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss) * 1024, "host peak RSS"


def run_once(seeds: int, episodes: int, mix_kinds: bool | None = None) -> dict:
    """The paper grid with ``seeds`` agents per setting: compile (untimed), then time it
    (``mix_kinds``: :class:`vdbejax.runs.RunOptions`'s)."""
    from vdbejax.envs.table_cleaning import make_mdp
    from vdbejax.methods.agents import paper_settings
    from vdbejax.runs import RunOptions, run_grid

    mdp, settings = make_mdp(), paper_settings()
    run = RunOptions(mix_kinds=mix_kinds)
    # The same call first: its programs are compiled for the very shapes timed below (a
    # shorter run compiles other chunk programs, and the timed run compiled its own).
    started = time.perf_counter()
    run_grid(mdp, settings, num_seeds=seeds, num_episodes=episodes, run=run)
    cold = time.perf_counter() - started
    started = time.perf_counter()
    result = run_grid(mdp, settings, num_seeds=seeds, num_episodes=episodes, run=run)
    wall = time.perf_counter() - started
    steps = int(result.lengths.astype(np.int64).sum())
    peak, where = _peak_bytes()
    return {"agents": len(settings) * seeds, "seeds": seeds, "episodes": episodes, "wall": wall,
            "mix_kinds": bool(result.meta["plan"]["mix_kinds"]),
            "cold": cold, "returns": result.returns,
            "train": float(result.meta["elapsed_seconds"]), "steps": steps,
            "steps_per_s": steps / max(wall, 1e-9), "peak_bytes": peak, "peak_where": where}


CPU_SCRIPT = textwrap.dedent("""
    import sys
    import numpy as np
    from vdbejax.envs.table_cleaning import make_mdp
    from vdbejax.runs import run_grid
    from vdbejax.methods.agents import paper_settings
    result = run_grid(make_mdp(), paper_settings(), num_seeds=int(sys.argv[1]),
                      num_episodes=int(sys.argv[2]))
    np.save(sys.argv[3], result.returns)
""")


def cpu_returns(seeds: int, episodes: int) -> np.ndarray:
    """The paper grid's returns ``[settings, seeds, episodes]`` on the CPU backend, from a
    subprocess (this process's backend is the accelerator's)."""
    with tempfile.TemporaryDirectory() as folder:
        out = Path(folder) / "returns.npy"
        subprocess.run([sys.executable, "-c", CPU_SCRIPT, str(seeds), str(episodes), str(out)],
                       check=True, env=dict(os.environ, JAX_PLATFORMS="cpu"))
        return np.load(out)


def cpu_agreement(returns: np.ndarray, reference: np.ndarray) -> dict:
    """How the device's paper grid agrees with the CPU's: settings agreeing (early and
    final windows, :func:`benchmarks.compare.agreement`) and bit-identical agents."""
    from benchmarks.compare import agreement
    from vdbejax.methods.agents import paper_settings

    settings = paper_settings()
    rows = agreement(returns, reference, settings)
    return {"settings": len(settings),
            "early": sum(row["early"][3] for row in rows),
            "final": sum(row["final"][3] for row in rows),
            "disagree": [row["setting"] for row in rows
                         if not (row["early"][3] and row["final"][3])],
            "identical": int(np.all(returns == reference, axis=-1).sum()),
            "agents": int(np.prod(returns.shape[:2]))}


def _fits(agents: int, episodes: int) -> bool:
    from vdbejax.runs.batching import check_run_size

    try:
        check_run_size(agents, episodes)
    except ValueError:
        return False
    return True


def sweep(episodes: int, max_agents: int, first_seeds: int = 20) -> list[dict]:
    """Grid runs with 20, 80, 320, … seeds per setting while they fit."""
    rows, seeds = [], first_seeds
    while 46 * seeds <= max_agents and _fits(46 * seeds, episodes):
        try:
            rows.append(run_once(seeds, episodes))
        except Exception as error:  # out of device memory: the sweep ends there
            rows.append({"agents": 46 * seeds, "error": f"{type(error).__name__}: {str(error)[:120]}"})
            break
        print(_row(rows[-1]), flush=True)
        seeds *= 4
    return rows


def _row(r: dict) -> str:
    if "error" in r:
        return f"| {r['agents']:,} | failed: {r['error']} | | | | |"
    return (f"| {r['agents']:,} | {r['episodes']:,} | {r['cold']:.2f} | {r['wall']:.2f} |"
            f" {r['steps']:,} |"
            f" {r['steps_per_s'] / 1e6:.1f} | {r['peak_bytes'] / 2**20:,.0f} ({r['peak_where']}) |")


def render(grid: dict, rows: list[dict], command: str, agree: dict | None = None,
           apart: dict | None = None) -> str:
    """The markdown section (``apart``: the paper grid run kind after kind)."""
    import jax

    device, _ = _device_summary()
    lines = [
        HEADING, "",
        f"- Date: {datetime.datetime.now(datetime.UTC):%Y-%m-%d %H:%M UTC}.",
        f"- Machine: {device}; jax {jax.__version__}, Python {platform.python_version()}.",
        f"- Command: `{command}`.", "",
        "Warm runs (the same call run first; its wall, compiling included, is the *cold*"
        " column).", "",
        f"Full paper grid (46 settings × 20 agents × {grid['episodes']:,} episodes):"
        f" {grid['wall']:.2f} s, {grid['steps']:,} agent-steps, {grid['steps_per_s'] / 1e6:.1f} M"
        f" agent-steps/s, peak memory {grid['peak_bytes'] / 2**20:,.0f} MiB ({grid['peak_where']})"
        f"; kinds {'mixed in one batch' if grid['mix_kinds'] else 'one after another'}."
        + ("" if apart is None else
           f" Kind after kind (`mix_kinds=False`): {apart['wall']:.2f} s warm,"
           f" {apart['cold']:.2f} s cold."),
        "", "| agents | episodes | cold s | wall s | agent-steps | M agent-steps/s | peak MiB |",
        "| --- | --- | --- | --- | --- | --- | --- |",
    ]
    lines += [_row(r) for r in rows]
    if agree is not None:
        lines += ["", f"Against the CPU backend (the same paper grid, per setting the agents'"
                  f" mean return over the first 300 and the last 100 episodes, bootstrap test of"
                  f" `benchmarks.compare.agreement`): {agree['early']}/{agree['settings']}"
                  f" settings agree early, {agree['final']}/{agree['settings']} finally;"
                  f" {agree['identical']:,} of {agree['agents']:,} agents bit-identical."
                  + (f" Disagreeing: {', '.join(agree['disagree'])}." if agree["disagree"]
                     else "")]
    return "\n".join(lines) + "\n"


def write_section(path: Path, section: str) -> None:
    """Replace the section in ``path`` (up to the next ``## `` heading), or append it."""
    text = path.read_text() if path.exists() else ""
    if HEADING in text:
        start = text.index(HEADING)
        rest = text[start + len(HEADING):]
        end = rest.find("\n## ")
        tail = "" if end < 0 else rest[end + 1:]
        text = text[:start] + section + ("\n" + tail if tail else "")
    else:
        text = text.rstrip("\n") + ("\n\n" if text else "") + section
    path.write_text(text)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", required=True, help="markdown file that gets the section")
    parser.add_argument("--episodes", type=int, default=1000, help="episodes per agent (default 1000)")
    parser.add_argument("--max-agents", type=int, default=2_000_000,
                        help="largest sweep size in agents (default 2,000,000)")
    parser.add_argument("--quick", action="store_true", help="tiny sizes: a smoke test")
    args = parser.parse_args(argv)
    episodes = 20 if args.quick else args.episodes
    max_agents = 46 * 8 if args.quick else args.max_agents
    command = "python -m benchmarks.gpu " + " ".join(argv if argv is not None else [])
    grid = run_once(2 if args.quick else 20, episodes)
    print(f"grid: {grid['wall']:.2f} s, {grid['steps_per_s'] / 1e6:.1f} M agent-steps/s", flush=True)
    apart = run_once(grid["seeds"], episodes, mix_kinds=False) if grid["mix_kinds"] else None
    if apart is not None:
        print(f"grid, kind after kind: {apart['wall']:.2f} s", flush=True)
    agree = cpu_agreement(grid["returns"], cpu_returns(grid["seeds"], episodes))
    print(f"against the CPU: {agree['final']}/{agree['settings']} settings agree finally,"
          f" {agree['identical']} agents bit-identical", flush=True)
    rows = sweep(episodes, max_agents, first_seeds=2 if args.quick else 20)
    write_section(Path(args.out), render(grid, rows, command.strip(), agree, apart))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
