"""The paper grid through ``vdbejax.run_grid``, called again and again in one process
(the warm in-process grid time): each call's wall time and the part of it spent getting
its programs (the first call traces them; later calls find them by their trace key,
`vdbejax/engine/programs.py`).

    python -m benchmarks.in_process [--calls 4] [--seeds 20] [--episodes 1000] [--json]

The first call also compiles or reads JAX's persistent cache; the later ones are the warm
in-process time. ``python -m benchmarks.par`` runs this beside ``benchmarks.compare``'s
numba-2t worker, interleaved, and prints the ratios.
"""
from __future__ import annotations

import argparse
import json
import sys
import time


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--calls", type=int, default=4, help="calls of run_grid (default 4)")
    parser.add_argument("--seeds", type=int, default=20)
    parser.add_argument("--episodes", type=int, default=1000)
    parser.add_argument("--threads", type=int, default=None,
                        help="worker threads (default: the CPUs this process may use)")
    parser.add_argument("--json", action="store_true",
                        help="print one JSON object: each call's wall and programs seconds")
    args = parser.parse_args(argv)

    import vdbejax
    from vdbejax import engine
    from vdbejax.envs.table_cleaning import make_mdp
    from vdbejax.methods.agents import paper_settings

    mdp, settings = make_mdp(), paper_settings()
    calls = []
    for call in range(args.calls):
        started, programs = time.perf_counter(), engine.compile_seconds()
        vdbejax.run_grid(mdp, settings, num_seeds=args.seeds, num_episodes=args.episodes,
                         threads=args.threads)
        calls.append({"wall": time.perf_counter() - started,
                      "programs": engine.compile_seconds() - programs})
        if not args.json:
            print(f"call {call + 1}: {calls[-1]['wall']:.2f} s, getting the programs "
                  f"{calls[-1]['programs']:.2f} s", flush=True)
    if args.json:
        print(json.dumps({"calls": calls}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
