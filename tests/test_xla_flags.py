"""vdbejax raises XLA's small-while-loop threshold so the CPU engine's per-agent loops
compile natively; without it the engine warns and falls back to the lockstep strategy,
with the same results."""
from __future__ import annotations

import os
import subprocess
import sys

import pytest

from vdbejax._xla_flags import SMALL_WHILE_LOOP_BYTES, with_small_loop_threshold

OPTION = f"xla_cpu_small_while_loop_byte_threshold={SMALL_WHILE_LOOP_BYTES}"


@pytest.mark.parametrize(
    "flags, expected",
    [
        ("", f"--xla_backend_extra_options={OPTION}"),
        ("--xla_force_host_platform_device_count=4",
         f"--xla_force_host_platform_device_count=4 --xla_backend_extra_options={OPTION}"),
        ("--xla_backend_extra_options=xla_cpu_fold_all_constants=true",
         f"--xla_backend_extra_options=xla_cpu_fold_all_constants=true,{OPTION}"),
        ("--xla_backend_extra_options=xla_cpu_small_while_loop_byte_threshold=5",
         "--xla_backend_extra_options=xla_cpu_small_while_loop_byte_threshold=5"),
    ],
)
def test_threshold_is_added_once_and_user_values_win(flags, expected):
    assert with_small_loop_threshold(flags) == expected
    assert with_small_loop_threshold(expected) == expected


SCRIPT = """
import warnings
import numpy as np
import vdbejax
from vdbejax import engine
from vdbejax.methods.agents import make_agent, paper_settings, stack_agents
from vdbejax.envs.table_cleaning import make_mdp
params = engine.broadcast_agents(stack_agents([make_agent(s) for s in paper_settings()[::9]]), 2)
keys = np.tile(engine.agent_keys(0, 2), (6, 1))
with warnings.catch_warnings(record=True) as caught:
    warnings.simplefilter("always")
    run = engine.run_agents(make_mdp(), params, keys, 15)
print(engine.native_step_loops(), run.strategy, len(caught), repr(run.returns.sum()))
"""


def _run(env_extra: dict[str, str]) -> list[str]:
    env = {k: v for k, v in os.environ.items() if k != "XLA_FLAGS"}
    env.update(env_extra)
    out = subprocess.run([sys.executable, "-c", SCRIPT], env=env, capture_output=True,
                         text=True, timeout=300, check=True)
    return out.stdout.split()


def test_engine_loops_are_native_and_without_the_flag_lockstep_gives_the_same():
    native, strategy_on, warnings_on, total_on = _run({})
    assert (native, strategy_on, warnings_on) == ("True", "sequential", "0")
    slow, strategy_off, warnings_off, total_off = _run({"VDBEJAX_XLA_FLAGS": "off"})
    assert (slow, strategy_off, warnings_off) == ("False", "lockstep", "1")
    assert total_off == total_on
