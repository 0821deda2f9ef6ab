"""Task families by name (issue 48, point 2): random MDPs (``garnet:SxAxB``) and generated
table-cleaning variants (``variant:NxK``) give every agent its own instance, like the
bandits."""
from __future__ import annotations

import dataclasses
import json

import jax
import numpy as np
import pytest

from vdbejax import cli, engine
from vdbejax.envs.solvers import best_return, uniform_random_return
from vdbejax.envs.suite import FAMILY_NAMES, NAMES, make_suite_family, make_suite_task, task_info
from vdbejax.envs.suite.garnet import garnet_family
from vdbejax.envs.table_cleaning import make_variant
from vdbejax.envs.table_cleaning.starts import start_codes
from vdbejax.methods.agents import Setting, make_agent, stack_agents
from vdbejax.runs import run_grid

SETTINGS = [Setting("qlearning", "egreedy", 0.1), Setting("sarsa", "vdbe", 1.0)]
SEEDS, EPISODES = 3, 12


def same_tables(a, b) -> bool:
    """Equal trees: the same leaves (bits), static fields (the name) and structure."""
    leaves_a, tree_a = jax.tree.flatten(a)
    leaves_b, tree_b = jax.tree.flatten(b)
    return tree_a == tree_b and all(np.array_equal(np.asarray(x), np.asarray(y))
                                    for x, y in zip(leaves_a, leaves_b, strict=True))


def one_line_error(call, match: str) -> None:
    with pytest.raises(ValueError, match=match) as caught:
        call()
    assert "\n" not in str(caught.value)


def assert_each_agent_meets_its_instance(family, seed: int) -> None:
    """A run of ``family`` gives agent (setting c, seed index i) exactly the bits of that
    agent alone on ``family.generate((seed, i))``."""
    result = run_grid(family, SETTINGS, num_seeds=SEEDS, num_episodes=EPISODES, seed=seed)
    keys = engine.agent_keys(seed, SEEDS)
    for c, setting in enumerate(SETTINGS):
        params = engine.broadcast_agents(stack_agents([make_agent(setting)]), 1)
        for i in range(SEEDS):
            alone = engine.run_agents(family.generate((seed, i)), params, keys[i:i + 1],
                                      EPISODES)
            assert np.array_equal(alone.returns[0], result.returns[c, i])
            assert np.array_equal(alone.lengths[0], result.lengths[c, i])
    meta = result.meta
    assert meta["instances"] == "per-agent"
    assert meta["instance_best_returns"] == pytest.approx(
        [best_return(family.generate((seed, i))) for i in range(SEEDS)])


# ------------------------------------------------------------------ garnet:SxAxB
def test_garnet_by_name_is_the_instance_of_seed_0_of_its_family():
    named = make_suite_task("garnet:6x3x2")
    assert same_tables(named, garnet_family(6, 3, 2, name="garnet:6x3x2").generate((0,)))
    assert named.name == "garnet:6x3x2" and int(named.max_steps) == 20
    assert task_info("garnet:6x3x2").horizon == 20 and "Archibald" in task_info(
        "garnet:6x3x2").source
    assert int(make_suite_task("garnet:6x3x2", max_steps=7).max_steps) == 7
    assert make_suite_family("garnet:6x3x2", shared=True).instance == 0
    assert make_suite_family("garnet:6x3x2").instance is None
    assert "garnet:SxAxB" in NAMES and {"garnet", "variant"} <= set(FAMILY_NAMES)


@pytest.mark.parametrize("name", ["garnet:0x2x1", "garnet:2x0x1", "garnet:2x2x3",
                                  "garnet:3x2x0", "garnet:65537x1x1"])
def test_bad_garnet_sizes_are_one_line_errors(name):
    from vdbejax.studies.task_names import make_task

    one_line_error(lambda: make_suite_task(name),
                   rf"^name='{name}' is invalid: garnet:SxAxB needs 1 <= S")
    one_line_error(lambda: make_suite_family(name), rf"^name='{name}' is invalid")
    one_line_error(lambda: make_task(name), rf"^task='{name}' is invalid: garnet:SxAxB")


@pytest.mark.parametrize("name", ["garnet", "garnet:", "garnet:5x2", "garnet:05x2x2",
                                  "garnet:5x2x2x1", "garnet:5xx2"])
def test_malformed_garnet_names_list_the_allowed(name):
    one_line_error(lambda: make_suite_task(name), r"is invalid: must be one of riverswim,.*"
                                                  r"garnet:SxAxB")


def test_a_shared_garnet_family_is_the_named_task_bit_for_bit():
    shared = run_grid(make_suite_family("garnet:5x2x2", shared=True), SETTINGS,
                      num_seeds=SEEDS, num_episodes=EPISODES, seed=2)
    named = run_grid(make_suite_task("garnet:5x2x2"), SETTINGS, num_seeds=SEEDS,
                     num_episodes=EPISODES, seed=2)
    assert np.array_equal(shared.returns, named.returns)
    assert shared.meta["instances"] == "shared"


def test_a_garnet_run_gives_each_agent_the_instance_of_its_seed_index():
    assert_each_agent_meets_its_instance(make_suite_family("garnet:6x3x2"), seed=4)


# ------------------------------------------------------------------ variant:NxK
@pytest.mark.parametrize("sizes", [(2, 1), (3, 1), (2, 2)])
def test_the_start_states_of_a_variant(sizes):
    """Hand free at home, goblets on sections (a multiset), not every section clean."""
    n, k = sizes
    codes = start_codes(n, k)
    count = {(2, 1): 2 * 3, (3, 1): 3 * 7, (2, 2): 3 * 3}[sizes]
    assert len(codes) == len(set(codes.tolist())) == count
    assert np.all(np.diff(codes) > 0)
    env = make_variant(n, k)
    fields = np.stack([np.asarray(env.decode(code)) for code in codes])
    assert np.all(fields[:, 0] == 0) and np.all(fields[:, 1] == n)  # free, at home
    assert np.all(fields[:, 2:2 + k] < n)  # on sections
    assert np.all(np.diff(fields[:, 2:2 + k], axis=1) >= 0)  # sorted: one code a multiset
    assert not np.any(fields[:, 2 + k:].all(axis=1))  # not solved already
    own, _ = env.start_distribution()
    assert set(own.tolist()) < set(codes.tolist())  # the variant's own starts among them


def test_variant_instances_differ_from_the_variant_only_in_their_one_start_state():
    named = make_suite_task("variant:2x1", max_steps=40)
    family = make_suite_family("variant:2x1", max_steps=40)
    assert family.name == "variant:2x1" and family.instance is None
    assert family.parameters == {}
    starts = named.index_of(start_codes(2, 1))
    drawn = set()
    for i in range(12):
        instance = family.generate((0, i))
        start = np.asarray(instance.start_probability)
        assert start.dtype == np.float32 and start.sum() == 1.0
        (state,) = np.nonzero(start)[0]
        assert state in starts
        drawn.add(int(state))
        # the variant itself (its name, states, tables) but for where it starts
        assert same_tables(dataclasses.replace(
            instance, start_probability=named.start_probability), named)
        assert best_return(instance) > uniform_random_return(instance)  # solvable
        assert same_tables(instance, family.generate((0, i)))  # a pure function of entropy
    assert len(drawn) >= 3  # the instances differ
    fail = make_suite_family("variant:2x1", invalid_action="fail").generate((0, 0))
    reference = make_suite_task("variant:2x1", invalid_action="fail")
    assert np.array_equal(np.asarray(fail.terminal), np.asarray(reference.terminal))


def test_a_variant_run_gives_each_agent_the_instance_of_its_seed_index():
    assert_each_agent_meets_its_instance(make_suite_family("variant:2x1", max_steps=30),
                                         seed=1)


def test_what_the_families_refuse_is_one_line():
    one_line_error(lambda: make_suite_family("variant:2x1", shared=True),
                   r"^task='variant:2x1' has no shared instance .*--instances per-agent$")
    one_line_error(lambda: make_suite_family("chain:5"),
                   r"^task='chain:5' has no generator of instances: .* need one of .*testbed:N,"
                   r" garnet:SxAxB")
    one_line_error(lambda: make_suite_family("table_cleaning"), r"has no generator")
    one_line_error(lambda: make_suite_family("garnet:4x2x2", invalid_action="fail"),
                   r"^invalid_action=.fail. is invalid with task=.garnet:4x2x2.")
    one_line_error(lambda: make_suite_family("variant:1x1"), r"^num_sections=1 is invalid")


# ------------------------------------------------------------------ command line
def test_the_cli_runs_garnet_and_variant_instances_per_agent(tmp_path, capsys):
    out = tmp_path / "garnet"
    argv = ["--learners", "qlearning", "--explorers", "egreedy", "--axis", "epsilon=0.1",
            "--seeds", "3", "--episodes", "10", "--no-figures", "--quiet", "--out"]
    assert cli.main(["run", "--task", "garnet:5x2x2", "--instances", "per-agent", *argv,
                     str(out)]) in (0, None)
    meta = json.loads((out / "meta.json").read_text())
    assert meta["instances"] == "per-agent" and len(meta["instance_best_returns"]) == 3
    family = make_suite_family("garnet:5x2x2")
    assert meta["instance_best_returns"] == pytest.approx(
        [best_return(family.generate((0, i))) for i in range(3)])
    capsys.readouterr()
    assert cli.main(["run", "--task", "chain:5", "--instances", "per-agent", *argv,
                     str(tmp_path / "chain")]) == 2
    assert "has no generator of instances" in capsys.readouterr().err
    assert cli.main(["run", "--task", "variant:2x1", "--axis", "task.instance=1,2", *argv,
                     str(tmp_path / "shared")]) == 2
    assert "need an instance per agent, --instances per-agent" in capsys.readouterr().err
    assert not (tmp_path / "chain").exists() and not (tmp_path / "shared").exists()


def test_vdbejax_list_shows_garnet_and_marks_the_families(capsys):
    assert cli.main(["list", "tasks"]) == 0
    text = capsys.readouterr().out
    lines = text.splitlines()
    garnet = next(line for line in lines if line.startswith("  garnet:SxAxB  "))
    assert "Garnet MDP" in garnet and garnet.endswith("[--instances per-agent]")
    for form in ("variant:NxK", "testbed:N", "gaussian_bandit:N"):
        assert next(line for line in lines if line.startswith(f"  {form}  ")).endswith(
            "[--instances per-agent]")
    for form in ("chain:N", "table_cleaning"):
        assert "per-agent" not in next(line for line in lines
                                       if line.startswith(f"  {form}  "))
    assert "S='states (required)'" in text
    assert cli.main(["list", "tasks", "--json"]) == 0
    tasks = {t["name"]: t for t in json.loads(capsys.readouterr().out)["tasks"]}
    assert tasks["garnet:SxAxB"]["parameters"]["max_steps"] == 20
    assert tasks["garnet:SxAxB"]["instances"] == "per-agent"
    assert "instances" not in tasks["chain"]
