"""Can the lockstep's step go into one Pallas kernel on a GPU? What Pallas's GPU lowerings
take, asked on any machine.

    python -m benchmarks.pallas_lowering [--json]

Each case is a Pallas kernel doing what every iteration of the step does first: each of
16 lanes reads its agent's row of A action values from the flat Q-table buffer
(``[lanes · S · A]``, S = 108 as on the paper's task) and takes its argmax. The kernel is
lowered for CUDA (``jit(...).trace(...).lower(lowering_platforms=("cuda",))``: no GPU
needed, nothing is compiled or run) with the Triton lowering and with Pallas's default
GPU lowering (Mosaic GPU), and run in interpret mode on this machine's CPU. It prints
what each lowering says: the engine's rows are A wide, A is the task's (7 on the paper's
task) and a plug-in sees the row whole.
"""
from __future__ import annotations

import argparse
import json
import sys
from typing import Any

LANES, STATES = 16, 108


def _kernel(actions: int) -> Any:
    import jax.numpy as jnp

    def kernel(q_ref: Any, state_ref: Any, out_ref: Any) -> None:
        rows = state_ref[...][:, None] * actions + jnp.arange(actions)[None, :]
        out_ref[...] = jnp.argmax(q_ref[rows], axis=1).astype(jnp.int32)  # a row per lane
    return kernel


def lower(actions: int, backend: str) -> dict[str, Any]:
    """The case with ``actions`` actions, lowered by ``backend`` (``"triton"``,
    ``"mosaic_gpu"`` for CUDA; ``"interpret"`` run here)."""
    import jax
    import jax.numpy as jnp
    from jax.experimental import pallas as pl
    from jax.experimental.pallas import triton as pallas_triton

    options: dict[str, Any] = {"interpret": True} if backend == "interpret" else {}
    if backend == "triton":
        options["compiler_params"] = pallas_triton.CompilerParams(num_warps=4)

    def call(q: Any, states: Any) -> Any:
        return pl.pallas_call(_kernel(actions), **options,
                              out_shape=jax.ShapeDtypeStruct((LANES,), jnp.int32))(q, states)

    q = jnp.arange(LANES * STATES * actions, dtype=jnp.float32) % 13
    states = jnp.arange(LANES, dtype=jnp.int32) * 5 % STATES
    row = {"actions": actions, "lowering": backend}
    try:
        if backend == "interpret":
            expected = jnp.argmax(q.reshape(-1, actions)[states], axis=1)
            row["ok"] = bool(jnp.all(jax.jit(call)(q, states) == expected))
            row["says"] = "ran on the CPU, the argmax of every row" if row["ok"] else "wrong"
        else:
            jax.jit(call).trace(q, states).lower(lowering_platforms=("cuda",))
            row["ok"], row["says"] = True, "lowered"
    except Exception as error:  # what the lowering refuses, in its words
        row["ok"], row["says"] = False, f"{type(error).__name__}: {str(error).splitlines()[0]}"
    return row


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--json", action="store_true", help="one JSON object")
    args = parser.parse_args(argv)
    import jax

    rows = [lower(actions, backend) for actions in (7, 8)
            for backend in ("triton", "mosaic_gpu", "interpret")]
    if args.json:
        print(json.dumps({"jax": jax.__version__, "rows": rows}))
        return 0
    print(f"jax {jax.__version__}; {LANES} lanes, a row of A values each from a"
          f" [{LANES}·{STATES}·A] table\n")
    print("| A | lowering | accepted | what it says |\n| --- | --- | --- | --- |")
    for row in rows:
        print(f"| {row['actions']} | {row['lowering']} | {'yes' if row['ok'] else 'no'} |"
              f" {row['says'][:200]} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
