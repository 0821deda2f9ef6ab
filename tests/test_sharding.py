"""The agent axis sharded over several devices: bit-identical to one device.

Four CPU devices are simulated in a subprocess with
``XLA_FLAGS=--xla_force_host_platform_device_count=4`` (the flag must be set before JAX
starts, so it cannot run in the pytest process); two for a run with an instance per agent."""
from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
from small_grid import assert_same_curves, run_small

from vdbejax.engine.distributed import pad_agents, select_devices, unpad_agents
from vdbejax.results.grid_result import GridResult

TESTS = Path(__file__).parent

#: Runs in a process with 4 CPU devices; saves each result for comparison here.
FOUR_DEVICE_SCRIPT = textwrap.dedent(
    """
    import json, sys
    sys.path.insert(0, {tests!r})
    import jax, numpy as np
    from small_grid import SETTINGS, budget_for, run_small, small_mdp
    from vdbejax.engine.distributed import agent_mesh, shard_agents
    from vdbejax.engine import agent_keys

    out = sys.argv[1]
    info = {{"devices": len(jax.devices())}}
    keys = shard_agents(agent_keys(0, 8), agent_mesh())
    info["key_shards"] = len(keys.sharding.device_set)
    info["shard_rows"] = sorted(s.data.shape[0] for s in keys.addressable_shards)
    # The engine keeps the agent states split: each device advances its own agents.
    from vdbejax.methods.agents import make_agent, stack_agents
    from vdbejax.engine import ChunkBounds, broadcast_agents, init_agent, run_chunk
    params = broadcast_agents(stack_agents([make_agent(SETTINGS[0])]), 8)  # one kind
    params, keys = shard_agents((params, agent_keys(0, 8)), agent_mesh())
    agents = jax.vmap(init_agent, in_axes=(None, 0, 0))(small_mdp(), params, keys)
    agents = run_chunk(small_mdp(), params, agents, ChunkBounds(start=np.int32(0), end=np.int32(2)), 2)[0]
    info["state_spec"] = str(agents.q.sharding.spec)
    info["state_shards"] = len(agents.q.sharding.device_set)

    run_small().save(out + "/all")                                  # 12 agents, 3 per device
    run_small(mix_kinds=True).save(out + "/mixed_kinds")            # 4 kinds in each batch
    run_small(settings=SETTINGS[:3]).save(out + "/padded")          # 9 agents padded to 12
    # One agent per device: the grid does not fit at once, it runs in 3 sharded batches.
    batched = run_small(memory_budget_bytes=budget_for(small_mdp(), 1))
    batched.save(out + "/batched")
    info["batched"] = [batched.meta["devices"], batched.meta["batches"],
                       batched.meta["agents_per_batch"]]
    info["plan"] = batched.meta["plan"]
    try:  # the plan refuses what sharded agents cannot do, rather than rewrite it
        run_small(strategy="sequential")
    except ValueError as error:
        info["sequential"] = str(error)
    from vdbejax.runs import UntilSolved
    from vdbejax.envs.table_cleaning import make_mdp
    run_small(mdp=make_mdp(), num_episodes=160, chunk_episodes=16, stop=UntilSolved(fraction=0.5),
              memory_budget_bytes=budget_for(make_mdp(), 2, chunk_episodes=16)
              ).save(out + "/until_solved")

    # Sharded batches of 16 then 8 agents, chunks long enough for the engine to compact
    # the first batch down to 8 lanes: the two 8-lane programs must not be confused.
    mixed = run_small(num_seeds=6, chunk_episodes=24,
                      memory_budget_bytes=budget_for(small_mdp(), 4, chunk_episodes=24))
    mixed.save(out + "/seeds6")

    class Stop(Exception):
        pass

    calls = []
    def stop(done, total, elapsed):
        calls.append(done)
        if len(calls) == 5:
            raise Stop
    try:
        run_small(memory_budget_bytes=budget_for(small_mdp(), 1), checkpoint=out + "/ckpt.npz",
                  progress=stop)
    except Stop:
        pass
    run_small(checkpoint=out + "/ckpt.npz", resume=True).save(out + "/resumed")
    print(json.dumps(info))
    """
)


@pytest.fixture(scope="module")
def four_devices(tmp_path_factory):
    out = tmp_path_factory.mktemp("sharded")
    script = out / "four_devices.py"
    script.write_text(FOUR_DEVICE_SCRIPT.format(tests=str(TESTS)))
    env = dict(os.environ, XLA_FLAGS="--xla_force_host_platform_device_count=4",
               JAX_PLATFORMS="cpu")
    done = subprocess.run([sys.executable, str(script), str(out)], env=env,
                          capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr
    return out, json.loads(done.stdout.strip().splitlines()[-1])


@pytest.fixture(scope="module")
def reference():
    return run_small()


def test_agents_are_split_over_four_devices(four_devices):
    _, info = four_devices
    assert info["devices"] == 4
    assert info["key_shards"] == 4
    assert info["shard_rows"] == [2, 2, 2, 2]
    assert info["state_shards"] == 4 and "agents" in info["state_spec"]


def test_four_devices_equal_one_device(four_devices, reference):
    out, _ = four_devices
    sharded = GridResult.load(out / "all")
    assert sharded.meta["devices"] == 4
    assert_same_curves(reference, sharded)


def test_kinds_mixed_in_sharded_batches_equal_one_device(four_devices, reference):
    out, _ = four_devices
    mixed = GridResult.load(out / "mixed_kinds")
    assert mixed.meta["plan"]["mix_kinds"] is True and mixed.meta["devices"] == 4
    assert_same_curves(reference, mixed)


def test_compacted_and_sharded_batches_of_one_shape_coexist(four_devices, reference):
    out, _ = four_devices
    seeds6 = GridResult.load(out / "seeds6")
    assert seeds6.meta["batches"] == 2  # 16 + 8 agents
    np.testing.assert_array_equal(seeds6.returns[:, :3], reference.returns)
    np.testing.assert_array_equal(seeds6.lengths[:, :3], reference.lengths)


def test_padding_agents_are_dropped(four_devices, reference):
    out, _ = four_devices
    padded = GridResult.load(out / "padded")
    assert padded.returns.shape[0] == 3
    np.testing.assert_array_equal(padded.returns, reference.returns[:3])
    np.testing.assert_array_equal(padded.lengths, reference.lengths[:3])


def test_grid_larger_than_one_device_budget_runs_in_sharded_batches(four_devices, reference):
    out, info = four_devices
    assert info["batched"] == [4, 3, 4]  # 4 devices, 3 batches of 4 agents
    assert_same_curves(reference, GridResult.load(out / "batched"))


def test_the_plan_states_the_sharding_and_refuses_what_it_cannot_do(four_devices):
    _, info = four_devices
    assert info["plan"] == {"devices": 4, "processes": 1, "sharded": True,
                            "strategy": "lockstep",
                            "strategy_rule": "auto: agents sharded over several devices",
                            "compact": False, "mix_kinds": False, "agents_per_batch": 4,
                            "memory_budget_bytes": info["plan"]["memory_budget_bytes"]}
    assert info["sequential"].startswith("strategy='sequential' is invalid with devices=4")


def test_until_solved_sharded_in_batches_equals_one_device(four_devices):
    from vdbejax.runs import UntilSolved

    out, _ = four_devices
    from vdbejax.envs.table_cleaning import make_mdp

    sharded = GridResult.load(out / "until_solved")
    one = run_small(mdp=make_mdp(), num_episodes=160, chunk_episodes=16,
                    stop=UntilSolved(fraction=0.5))
    assert sharded.meta["plan"]["sharded"] and not one.meta["plan"]["sharded"]
    assert sharded.meta["batches"] > 1
    assert one.episodes_run is not None and (one.episodes_run < 160).any()
    np.testing.assert_array_equal(sharded.episodes_run, one.episodes_run)
    assert_same_curves(sharded, one)


def test_sharded_batched_run_resumes_bit_identically(four_devices, reference):
    out, _ = four_devices
    assert_same_curves(reference, GridResult.load(out / "resumed"))


def test_pad_and_unpad_agents():
    tree = {"a": np.arange(5), "b": np.arange(10).reshape(5, 2)}
    padded, count = pad_agents(tree, 4)
    assert count == 5
    np.testing.assert_array_equal(padded["a"], [0, 1, 2, 3, 4, 4, 4, 4])
    np.testing.assert_array_equal(padded["b"][-1], [8, 9])
    np.testing.assert_array_equal(unpad_agents(padded, count)["b"], tree["b"])
    same, _ = pad_agents(tree, 5)
    assert same is tree


def test_select_devices_checks_the_count():
    assert len(select_devices()) >= 1
    with pytest.raises(ValueError, match=r"devices=1000 is invalid: only \d+ device"):
        select_devices(1000)
    with pytest.raises(ValueError, match="devices=0 is invalid"):
        select_devices(0)


#: One of two processes of a "multi-host" run on this machine (2 CPU devices each).
TWO_PROCESS_SCRIPT = textwrap.dedent(
    """
    import sys
    sys.path.insert(0, {tests!r})
    import jax
    port, process_id, out = sys.argv[1], int(sys.argv[2]), sys.argv[3]
    jax.distributed.initialize(coordinator_address="127.0.0.1:" + port, num_processes=2,
                               process_id=process_id)
    from small_grid import run_small
    jax.devices()  # the backend's start waits for both processes: the lag starts after it
    if process_id == 1:  # shares end far apart: past the collectives' own 30 s wait
        import time
        time.sleep(32)
    result = run_small(checkpoint=out + "/ckpt.npz")
    assert result.meta["devices"] == 4 and result.meta["processes"] == 2, result.meta
    result.save(out + f"/process{{process_id}}")
    """
)


def free_port() -> int:
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_two_processes_like_two_hosts_equal_one_process(tmp_path, reference):
    script = tmp_path / "two_processes.py"
    script.write_text(TWO_PROCESS_SCRIPT.format(tests=str(TESTS)))
    env = dict(os.environ, XLA_FLAGS="--xla_force_host_platform_device_count=2",
               JAX_PLATFORMS="cpu")
    port = str(free_port())
    processes = [subprocess.Popen([sys.executable, str(script), port, str(i), str(tmp_path)],
                                  env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                  text=True) for i in range(2)]
    for process in processes:
        _, err = process.communicate(timeout=600)
        assert process.returncode == 0, err
    for i in range(2):  # every process holds the whole, gathered result
        assert_same_curves(reference, GridResult.load(tmp_path / f"process{i}"))
    assert sorted(p.name for p in tmp_path.glob("ckpt*")) == [  # each with its episode log
        "ckpt.process0of2.npz", "ckpt.process0of2.npz.episodes",
        "ckpt.process1of2.npz", "ckpt.process1of2.npz.episodes"]


#: Runs in a process with 2 CPU devices: a run with an instance per agent (9 agents, not a
#: multiple of 2: padded) on one device and on two, whole and in batches, resumed too.
TWO_DEVICE_INSTANCES_SCRIPT = textwrap.dedent(
    """
    import json, sys
    import jax, numpy as np
    from vdbejax.envs.suite.bandits import bandit_family
    from vdbejax.envs.suite.garnet import garnet_family
    from vdbejax.methods.agents import Setting, table_layout
    from vdbejax.runs import RunOptions, prepare_grid, run_grid, run_prepared
    from vdbejax.runs.batching import bytes_per_agent, instance_bytes, mdp_bytes

    out = sys.argv[1]
    settings = [Setting("qlearning", "egreedy", 0.1), Setting("sarsa", "vdbe", 1.0),
                Setting("qlearning", "vdbe_softmax", 1.0)]
    grid = dict(num_seeds=3, num_episodes=24, seed=1)
    run = RunOptions(chunk_episodes=8, record_optimal=True)
    info = {"devices": len(jax.devices())}

    def save(name, result):
        np.savez(out + "/" + name, returns=result.returns, lengths=result.lengths,
                 optimal=result.optimal_actions)
        info[name] = result.meta["plan"]

    families = {"testbed": bandit_family("testbed", 5, name="testbed:5"),
                "garnet": garnet_family(5, 3, 2, max_steps=6)}
    for name, family in families.items():
        for devices in (1, 2):
            result = run_grid(family, settings, run=run.replace(devices=devices), **grid)
            save(f"{name}{devices}", result)
    # Two agents per device by the plan's own count: batches of 4, 4 and 1 (padded to 2).
    family = families["garnet"]
    prepared = prepare_grid(family, settings, run=run, **grid)
    budget = mdp_bytes(prepared.mdp) + 2 * bytes_per_agent(
        prepared.mdp, 8, table_layout(prepared.params),
        instance_bytes(prepared.instances, record_optimal=True))
    batched = run.replace(devices=2, memory_budget_bytes=budget)
    save("batched", run_grid(family, settings, run=batched, **grid))

    class Stop(Exception):
        pass

    def stop(done, total, elapsed):
        if done >= 200:  # 96 + 96 + 8: the last batch (1 agent, padded) resumes mid-way
            raise Stop

    checkpointed = batched.replace(checkpoint=out + "/ckpt.npz")
    try:
        run_prepared(prepare_grid(family, settings, run=checkpointed.replace(progress=stop),
                                  **grid))
    except Stop:
        info["stopped"] = True
    resumed = run_prepared(prepare_grid(family, settings, run=checkpointed.replace(resume=True),
                                        **grid))
    info["resumed_from"] = resumed.meta["resumed_from_agent_episodes"]
    save("resumed", resumed)
    print(json.dumps(info))
    """
)


def test_an_instance_per_agent_on_two_devices_equals_one_device(tmp_path):
    script = tmp_path / "two_devices.py"
    script.write_text(TWO_DEVICE_INSTANCES_SCRIPT)
    env = dict(os.environ, XLA_FLAGS="--xla_force_host_platform_device_count=2",
               JAX_PLATFORMS="cpu")
    done = subprocess.run([sys.executable, str(script), str(tmp_path)], env=env,
                          capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr
    info = json.loads(done.stdout.strip().splitlines()[-1])
    assert info["devices"] == 2
    for name in ("testbed", "garnet"):
        assert not info[f"{name}1"]["sharded"] and info[f"{name}2"]["sharded"]
        assert info[f"{name}2"]["agents_per_batch"] == 9  # one batch, padded to 10
    assert info["batched"]["agents_per_batch"] == 4  # 2 per device: the instances counted
    assert info["stopped"] and info["resumed_from"] == 200
    for name, reference in [("testbed2", "testbed1"), ("garnet2", "garnet1"),
                            ("batched", "garnet1"), ("resumed", "garnet1")]:
        one, two = np.load(tmp_path / f"{reference}.npz"), np.load(tmp_path / f"{name}.npz")
        assert one["returns"].shape == (3, 3, 24)
        for field in ("returns", "lengths", "optimal"):  # bit for bit, NaN for NaN
            np.testing.assert_array_equal(two[field], one[field], err_msg=f"{name}: {field}")
    assert np.load(tmp_path / "garnet1.npz")["optimal"].sum() > 0
