"""Where the lockstep strategy's time goes: its loop body, its trips, its speed.

    python -m benchmarks.lockstep [--seeds 1000] [--episodes 50] [--lanes 2048]
                                  [--repeats 2] [--threads N] [--group-lanes 64,2048]
                                  [--accelerator-schedule] [--json]

For each kind of agent of the paper grid, and for one batch of all eight kinds (a kind
per lane, ``mix_kinds``), the lockstep block program at ``--lanes`` lanes is compiled and
its optimized HLO read: XLA operations (fusions) per loop iteration, and the bytes of
table-sized buffers (more elements than lanes × actions) copied per iteration. Then the
paper grid at ``--seeds`` seeds × ``--episodes`` episodes runs with the lockstep (kind
after kind, then the kinds mixed) and the sequential strategy, one after the other in
this process (each once to get its programs, then ``--repeats`` timed calls, best kept):
loop trips (iterations), host round trips (blocks run) and fusions run (each block's
fusions per iteration × its iterations: the kernels an accelerator would launch) per
chunk, and agent-steps/s of each; ``--group-lanes`` times the lockstep again with
batches of other sizes than :data:`vdbejax.engine.MAX_SAFE_BATCH`;
``--accelerator-schedule`` counts the lockstep's trips and fusions run as it is run on an
accelerator (:func:`vdbejax.engine.default_max_batch`, :func:`vdbejax.engine.mixes_kinds`).
"""
from __future__ import annotations

import argparse
import json
import re
import sys
import time
from typing import Any

_WHILE = re.compile(r"while\(.*?condition=%?([\w.\-]+), body=%?([\w.\-]+)")
_COPY = re.compile(r"= (\w+)\[([\d,]*)\]\{[^}]*\} copy\(")
_FUSION = re.compile(r"^\s*%?[\w.\-]+ = .*? fusion\(", re.MULTILINE)
_BYTES = {"pred": 1, "s8": 1, "u8": 1, "s16": 2, "u16": 2, "f16": 2, "bf16": 2,
          "s32": 4, "u32": 4, "f32": 4, "s64": 8, "u64": 8, "f64": 8}


def computation(hlo: str, name: str) -> str:
    """The text of computation ``name`` of an optimized HLO module."""
    start = re.search(rf"^%?{re.escape(name)} ", hlo, re.MULTILINE)
    if start is None:
        raise ValueError(f"computation {name!r} not found in the module")
    end = hlo.find("\n}\n", start.start())
    return hlo[start.start():end]


def loop_body(hlo: str, lanes: int, actions: int) -> dict[str, Any]:
    """The outermost ``while`` loop body of an optimized HLO module: its fusions, and its
    copies of buffers of more than ``lanes × actions`` elements (a table, or the chunk's
    return buffers: one iteration needs at most a row per lane)."""
    loop = _WHILE.search(hlo)
    if loop is None:
        raise ValueError("no while loop in the module")
    body = computation(hlo, loop.group(2))
    copies = []
    for dtype, dims in _COPY.findall(body):
        elements = 1
        for dim in filter(None, dims.split(",")):
            elements *= int(dim)
        if elements > lanes * actions:
            copies.append({"dtype": dtype, "shape": dims, "bytes": elements * _BYTES[dtype]})
    return {"fusions": len(_FUSION.findall(body)), "table_copies": copies,
            "table_bytes_copied": sum(copy["bytes"] for copy in copies)}


def block_program_hlo(settings: list[Any], lanes: int, chunk_length: int = 64) -> str:
    """The optimized HLO of the lockstep block program of ``settings``' kind, or of their
    kinds mixed in one batch (lanes split evenly between the settings)."""
    import jax
    import jax.numpy as jnp

    from vdbejax.engine import lockstep
    from vdbejax.engine.agent_state import for_task, init_agents
    from vdbejax.engine.kinds import KindSwitch
    from vdbejax.engine.programs import Programs
    from vdbejax.engine.step import ChunkBounds, ChunkBuffers, LoopLimits
    from vdbejax.envs.table_cleaning import make_mdp
    from vdbejax.runs import grid_agents

    mdp = make_mdp()
    params, keys = grid_agents(settings, lanes // len(settings))
    params = for_task(params, mdp)  # the task's facts, as run_agents hands them
    agents = jax.eval_shape(init_agents, mdp, params, keys)
    agent = (params.kinds[0] if len(params.kinds) == 1 else
             KindSwitch(kinds=tuple(params.kinds), kind=jnp.asarray(params.kind, jnp.int32)))
    lanes = len(keys)
    buffers = ChunkBuffers(returns=jax.ShapeDtypeStruct((lanes, chunk_length), jnp.float32),
                           lengths=jax.ShapeDtypeStruct((lanes, chunk_length), jnp.int32),
                           cut=jax.ShapeDtypeStruct((lanes, chunk_length), jnp.bool_),
                           optimal=None)  # no optimal record
    args = (mdp, agent, agents, buffers, ChunkBounds(start=jnp.int32(0), end=jnp.int32(1)),
            LoopLimits(max_iterations=jnp.int32(1), unroll=1), lockstep.start_support(mdp))
    return str(Programs().get(lockstep.block_program, args).as_text())


def kind_rows(lanes: int) -> list[dict[str, Any]]:
    """:func:`loop_body` of every kind of the paper grid at ``lanes`` lanes, and of all
    of them in one batch (``"mixed"``)."""
    from vdbejax.envs.table_cleaning import make_mdp
    from vdbejax.methods.agents import paper_settings

    actions = make_mdp().num_actions
    kinds: dict[str, Any] = {}
    for setting in paper_settings():
        kinds.setdefault(f"{setting.learner}/{setting.explorer}", setting)
    batches = {name: [setting] for name, setting in kinds.items()}
    batches[f"mixed ({len(kinds)} kinds)"] = list(kinds.values())
    return [{"kind": name, **loop_body(block_program_hlo(settings, lanes), lanes, actions)}
            for name, settings in batches.items()]


def timed_grid(strategy: str, seeds: int, episodes: int, repeats: int,
               threads: int | None, max_batch: int | None = None,
               mix_kinds: bool = False, **options: Any) -> dict[str, Any]:
    """The paper grid with ``strategy`` (the lockstep's kinds mixed in one batch with
    ``mix_kinds``; ``options``: more of :class:`vdbejax.engine.EngineOptions`): programs
    got once, then the best of ``repeats`` calls (one chunk); its loop trips and host
    round trips (blocks run)."""
    from vdbejax import engine
    from vdbejax.engine import lockstep
    from vdbejax.engine.programs import Programs
    from vdbejax.envs.table_cleaning import make_mdp
    from vdbejax.methods.agents import paper_settings
    from vdbejax.runs import grid_agents

    mdp = make_mdp()
    params, keys = grid_agents(paper_settings(), seeds)
    blocks, fusions_run = [0], [0]
    fusions_of: dict[int, int] = {}  # per block program: fusions per loop iteration
    real_get = Programs.get

    def counting_get(self: Any, function: Any, *args: Any, **kwargs: Any) -> Any:
        program = real_get(self, function, *args, **kwargs)
        if function is not lockstep.block_program:
            return program

        def counted(*call_args: Any) -> Any:  # one host round trip per block run
            blocks[0] += 1
            outputs = program(*call_args)
            if id(program) not in fusions_of:
                fusions_of[id(program)] = loop_body(program.as_text(), 1, 1)["fusions"]
            fusions_run[0] += fusions_of[id(program)] * int(outputs[2])  # × its iterations
            return outputs
        return counted

    def run() -> Any:
        return engine.run_agents(mdp, params, keys, episodes,
                                 engine.EngineOptions(chunk_episodes=episodes, strategy=strategy,
                                                      threads=threads, keep_final_state=False,
                                                      mix_kinds=mix_kinds, max_batch=max_batch,
                                                      **options))

    run()
    best, result, trips = float("inf"), None, 0
    Programs.get = counting_get  # type: ignore[method-assign]
    try:
        for _ in range(repeats):
            blocks[0] = fusions_run[0] = 0
            started = time.perf_counter()
            result = run()
            best, trips = min(best, time.perf_counter() - started), blocks[0]
    finally:
        Programs.get = real_get  # type: ignore[method-assign]
    assert result is not None
    steps = int(result.lengths.sum())
    return {"strategy": strategy + (" (kinds mixed)" if mix_kinds else ""), "agents": len(keys), "episodes": episodes,
            "seconds": round(best, 3), "agent_steps": steps,
            "agent_steps_per_s": round(steps / best),
            "max_batch": max_batch, "loop_trips_per_chunk": int(result.iterations),
            "host_round_trips_per_chunk": trips if strategy == "lockstep" else None,
            # What an accelerator launches: each iteration runs its program's fusions.
            "fusions_run_per_chunk": fusions_run[0] if strategy == "lockstep" else None}


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--seeds", type=int, default=1000, help="agents per setting")
    parser.add_argument("--episodes", type=int, default=50)
    parser.add_argument("--lanes", type=int, default=2048,
                        help="lanes of the block programs whose HLO is read")
    parser.add_argument("--repeats", type=int, default=2, help="timed calls (best kept)")
    parser.add_argument("--threads", type=int, default=None,
                        help="worker threads (default: the CPUs)")
    parser.add_argument("--group-lanes", default="",
                        help="also time the lockstep with groups of these many lanes"
                             " (comma-separated)")
    parser.add_argument("--accelerator-schedule", action="store_true",
                        help="also count the loop trips, host round trips and fusions run"
                             " of the lockstep as it runs on an accelerator (one thread,"
                             " blocks of a fixed trip count; batches of 2,048 lanes kind"
                             " after kind, then the default: every agent in one batch, kind"
                             " after kind and kinds mixed); its times are this CPU's")
    parser.add_argument("--json", action="store_true", help="one JSON object")
    args = parser.parse_args(argv)
    try:
        group_lanes = [int(part) for part in args.group_lanes.split(",") if part]
    except ValueError:
        parser.exit(2, f"--group-lanes must be comma-separated integers, got"
                       f" {args.group_lanes!r}\n")
    if any(lanes < 1 for lanes in group_lanes):
        parser.exit(2, f"--group-lanes must be at least 1, got {args.group_lanes!r}\n")
    for name in ("seeds", "episodes", "lanes", "repeats"):
        if getattr(args, name) < 1:
            parser.exit(2, f"--{name} must be at least 1, got {getattr(args, name)}\n")

    import vdbejax  # noqa: F401  (its XLA setting before JAX starts)

    report = {"kinds": kind_rows(args.lanes), "runs": [
        timed_grid(strategy, args.seeds, args.episodes, args.repeats, args.threads,
                   mix_kinds=mix)
        for strategy, mix in (("lockstep", False), ("lockstep", True), ("sequential", False))]}
    lock, mixed, seq = report["runs"]
    report["lockstep_over_sequential"] = round(
        lock["agent_steps_per_s"] / seq["agent_steps_per_s"], 3)
    report["mixed_over_kind_after_kind"] = round(
        mixed["agent_steps_per_s"] / lock["agent_steps_per_s"], 3)
    report["group_lanes"] = [
        timed_grid("lockstep", args.seeds, args.episodes, args.repeats, args.threads, lanes)
        for lanes in group_lanes]
    everyone = lock["agents"]
    report["accelerator_schedule"] = [
        timed_grid("lockstep", args.seeds, args.episodes, 1, 1, lanes, mix, fixed_blocks=True)
        for lanes, mix in ((2048, False), (everyone, False), (everyone, True))
    ] if args.accelerator_schedule else []
    if args.json:
        print(json.dumps(report))
        return 0
    print(f"lockstep loop body at {args.lanes} lanes, per iteration:")
    for row in report["kinds"]:
        print(f"  {row['kind']:<26} {row['fusions']:>3} fusions, "
              f"{row['table_bytes_copied']:>9,} bytes of tables copied")
    print(f"paper grid, {args.seeds} seeds × {args.episodes} episodes "
          f"({lock['agents']:,} agents):")
    for run in report["runs"]:
        trips = run["host_round_trips_per_chunk"]
        print(f"  {run['strategy']:<24} {run['seconds']:>7.2f} s  "
              f"{run['agent_steps_per_s'] / 1e6:>6.2f} M agent-steps/s  "
              f"loop trips {run['loop_trips_per_chunk']:,}"
              + ("" if trips is None else f", host round trips {trips:,}, fusions run"
                 f" {run['fusions_run_per_chunk']:,}"))
    print(f"  lockstep / sequential: {report['lockstep_over_sequential']:.2f}×; kinds mixed /"
          f" kind after kind: {report['mixed_over_kind_after_kind']:.2f}×")
    if report["accelerator_schedule"]:
        print("as on an accelerator (one thread, blocks of a fixed trip count):")
    for run in report["accelerator_schedule"]:
        print(f"  {run['strategy']:<24} batches of {run['max_batch']:>6,} lanes: loop trips"
              f" {run['loop_trips_per_chunk']:,}, host round trips"
              f" {run['host_round_trips_per_chunk']:,}, fusions run"
              f" {run['fusions_run_per_chunk']:,}")
    for run in report["group_lanes"]:
        print(f"  lockstep, groups of {run['max_batch']:>5,} lanes: {run['seconds']:>7.2f} s  "
              f"{run['agent_steps_per_s'] / 1e6:>6.2f} M agent-steps/s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
