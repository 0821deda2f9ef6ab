"""The engine's executables on disk (vdbejax._executables): reuse, keys, bad entries."""
from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from vdbejax import _executables, engine

ROOT = Path(__file__).resolve().parents[1]

# A small grid in a fresh process with JAX's persistent cache in argv[1]; prints what the
# disk copy did and the returns.
_SCRIPT = textwrap.dedent(
    """
    import json, sys
    import jax
    jax.config.update("jax_compilation_cache_dir", sys.argv[1])
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0)
    from vdbejax import _executables
    from vdbejax.experiment import run_grid
    from vdbejax.methods.agents import paper_settings
    from vdbejax.envs.table_cleaning import make_mdp
    result = run_grid(make_mdp(), paper_settings()[::9], num_seeds=3, num_episodes=6)
    print(json.dumps({"disk": _executables.disk_counts(),
                      "returns": result.returns.ravel().tolist()}))
    """
)


def _run(cache: Path, **env: str) -> dict:
    environment = {**os.environ, "JAX_PLATFORMS": "cpu", **env}
    environment.pop("JAX_COMPILATION_CACHE_DIR", None)
    done = subprocess.run([sys.executable, "-c", _SCRIPT, str(cache)], capture_output=True,
                          text=True, cwd=ROOT, env=environment, timeout=300, check=False)
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout.strip().splitlines()[-1])


def test_a_new_process_loads_the_programs_a_first_one_stored(tmp_path):
    # 1: only JAX's cache fills. 2: JAX's cache is warm but the disk copy empty: the
    # programs are compiled afresh and stored (a copy of an executable that JAX loaded from
    # its cache would fail to run). 3: everything comes from the disk copy.
    only_jax = _run(tmp_path, VDBEJAX_EXECUTABLE_CACHE="off")
    assert only_jax["disk"]["stored"] == 0 and only_jax["disk"]["loaded"] == 0
    first = _run(tmp_path)
    assert first["disk"]["stored"] >= 3 and first["disk"]["loaded"] == 0
    assert any((tmp_path / "vdbejax-executables").glob("*.pkl"))
    second = _run(tmp_path)
    assert second["disk"]["loaded"] == first["disk"]["stored"]
    assert second["disk"]["stored"] == 0
    assert second["returns"] == first["returns"] == only_jax["returns"]


@pytest.fixture
def disk(tmp_path, monkeypatch):
    """The disk copy in a temporary folder, with an empty in-process table."""
    monkeypatch.setattr(_executables, "disk_folder", lambda: tmp_path)
    monkeypatch.setattr(_executables, "_EXECUTABLES", {})
    return tmp_path


def _keys_program(seed: int, num_seeds: int = 3):
    return _executables.compiled(engine.state._agent_keys, (), {"seed": seed, "num_seeds": num_seeds})


def test_a_damaged_entry_is_ignored_and_rewritten(disk):
    expected = engine.agent_keys(11, 3)
    _keys_program(11)
    (entry,) = disk.glob("*.pkl")
    entry.write_bytes(b"not a pickle")
    _executables._EXECUTABLES.clear()
    np.testing.assert_array_equal(np.asarray(_keys_program(11)()), expected)
    assert entry.read_bytes() != b"not a pickle"  # compiled again and stored
    _executables._EXECUTABLES.clear()
    loaded_before = _executables.disk_counts()["loaded"]
    np.testing.assert_array_equal(np.asarray(_keys_program(11)()), expected)
    assert _executables.disk_counts()["loaded"] == loaded_before + 1


def test_an_entry_that_fails_to_run_is_deleted_and_compiled_again(disk):
    _keys_program(12)
    (entry,) = disk.glob("*.pkl")

    def broken(*args):
        raise RuntimeError("NOT_FOUND: Function convert_bitcast_fusion not found (type id: 1)")

    calls = []

    def recompile():
        calls.append(1)
        return lambda: "recompiled"

    wrapped = _executables._FromDisk(broken, entry, ("key",), recompile)
    assert wrapped() == "recompiled"
    assert calls == [1] and not entry.exists()
    assert wrapped() == "recompiled" and calls == [1]


def test_other_errors_of_a_loaded_entry_propagate(disk, tmp_path):
    def failing(*args):
        raise ValueError("bad argument")

    wrapped = _executables._FromDisk(failing, tmp_path / "x.pkl", ("key",), lambda: None)
    with pytest.raises(ValueError, match="bad argument"):
        wrapped()


def test_the_key_covers_static_arguments_signature_options_flags_and_source(monkeypatch):
    function = engine.state._agent_keys
    sig = _executables.signature((jnp.zeros(3, jnp.float32),))

    def key(static=None, sig=sig, options=None):
        return _executables.disk_key(function, static or {"seed": 1}, sig, options or {})

    base = key()
    assert key() == base
    assert key(static={"seed": 2}) != base
    assert key(sig=_executables.signature((jnp.zeros(4, jnp.float32),))) != base
    assert key(sig=_executables.signature((jnp.zeros(3, jnp.int32),))) != base
    assert key(sig=_executables.signature((np.float32(0.5) * jnp.ones(3),))) == base
    assert key(options={"xla_cpu_copy_insertion_use_region_analysis": True}) != base
    monkeypatch.setenv("XLA_FLAGS", os.environ.get("XLA_FLAGS", "") + " --xla_cpu_use_thunk_runtime=true")
    assert key() != base
    monkeypatch.undo()
    monkeypatch.setattr(_executables, "source_fingerprint", lambda: "edited")
    assert key() != base
    monkeypatch.undo()
    program = _executables.program_text(function.trace(seed=1, num_seeds=3))
    other = _executables.program_text(function.trace(seed=1, num_seeds=4))
    assert program != other
    assert _executables.disk_key(function, {"seed": 1}, sig, {}, program) != _executables.disk_key(
        function, {"seed": 1}, sig, {}, other)


# The grid of _SCRIPT with SARSA's target monkeypatched (argv[2] == "patched"): a warm
# disk copy must not serve the unpatched programs.
_PATCHED = _SCRIPT.replace(
    "from vdbejax.experiment import run_grid",
    "from vdbejax.experiment import run_grid\n"
    "from vdbejax.methods import learners\n"
    "if sys.argv[2] == 'patched':\n"
    "    learners.sarsa_target = lambda reward, discount, q_next, action: reward + 0.5",
)


def _run_patched(cache: Path, mode: str) -> dict:
    environment = {**os.environ, "JAX_PLATFORMS": "cpu"}
    environment.pop("JAX_COMPILATION_CACHE_DIR", None)
    done = subprocess.run([sys.executable, "-c", _PATCHED, str(cache), mode], capture_output=True,
                          text=True, cwd=ROOT, env=environment, timeout=300, check=False)
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout.strip().splitlines()[-1])


def test_a_monkeypatched_rule_is_never_served_the_stored_programs(tmp_path):
    plain = _run_patched(tmp_path, "plain")
    patched = _run_patched(tmp_path, "patched")
    assert patched["returns"] != plain["returns"]  # the new rule ran
    assert patched["disk"]["stored"] > 0  # its SARSA programs are new entries
    again = _run_patched(tmp_path, "patched")
    assert again["returns"] == patched["returns"] and again["disk"]["stored"] == 0


def test_multi_device_runs_twice_with_one_cache(tmp_path):
    flags = {"XLA_FLAGS": "--xla_force_host_platform_device_count=4"}
    first = _run(tmp_path, **flags)
    second = _run(tmp_path, **flags)
    assert second["returns"] == first["returns"] == _run(tmp_path)["returns"]


def test_the_source_fingerprint_changes_with_any_file_of_the_package():
    fingerprint = _executables.source_fingerprint()
    assert len(fingerprint) == 64 and fingerprint == _executables.source_fingerprint()


def test_only_vdbejax_functions_and_an_enabled_cache_use_the_disk(disk, monkeypatch):
    @jax.jit
    def outside(x):
        return x + 1

    sig = _executables.signature((jnp.zeros(2),))
    traced = engine.state._agent_keys.trace(seed=0, num_seeds=3)
    live = _executables.live_fingerprint()
    assert _executables._disk_path(outside, {}, sig, {}, traced, live) is None
    assert _executables._disk_path(engine.state._agent_keys, {"seed": 0}, sig, {}, traced,
                                   live) is not None
    monkeypatch.undo()  # the real disk_folder: off by the variable, else JAX's cache dir
    monkeypatch.setenv("VDBEJAX_EXECUTABLE_CACHE", "off")
    assert _executables.disk_folder() is None


def test_a_loaded_entry_recompiles_from_shapes_and_keeps_no_arrays_alive(disk):
    from vdbejax.methods.agents import make_agent, paper_settings, stack_agents
    from vdbejax.envs.table_cleaning import make_mdp

    mdp = make_mdp()
    params = stack_agents([make_agent(s) for s in paper_settings()[:3]])
    keys = engine.agent_keys(2, 3)
    args = (mdp, params, keys)
    expected = _executables.compiled(engine.init_agents, args, {})(*args)
    _executables._EXECUTABLES.clear()
    loaded = _executables.compiled(engine.init_agents, args, {})
    assert isinstance(loaded, _executables._FromDisk)
    # What the entry would recompile from: shapes only, no reference to the arrays.
    closure = [cell.cell_contents for cell in loaded._recompile.__closure__]
    assert not any(leaf is keys for cell in closure for leaf in jax.tree.leaves(cell))

    def broken(*_):
        raise RuntimeError("NOT_FOUND: Function fusion not found")

    loaded._executable = broken
    for got, want in zip(jax.tree.leaves(loaded(*args)), jax.tree.leaves(expected)):
        np.testing.assert_array_equal(np.asarray(got), np.asarray(want))


def test_programs_are_compiled_without_source_locations_and_compute_the_same(disk):
    # Locations are most of what a process parses when it loads a stored program.
    executable = _keys_program(11)
    text = executable.as_text()
    assert "op_name=" not in text and "source_file=" not in text
    plain = jax.jit(lambda **static: engine.state._agent_keys.__wrapped__(**static),
                    static_argnames=("seed", "num_seeds"))
    with_locations = plain.trace(seed=11, num_seeds=3).lower().compile()
    assert "op_name=" in with_locations.as_text()
    np.testing.assert_array_equal(np.asarray(executable()), np.asarray(with_locations()))
