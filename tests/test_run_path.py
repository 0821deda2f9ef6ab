"""The one run path: options checked once, a plan stated in meta.json, stop policies, and
the result-folder pipeline every training command shares (resume, reuse, one-line errors)."""
from __future__ import annotations

import json

import numpy as np
import pytest
from small_grid import (
    EPISODES,
    SEEDS,
    SETTINGS,
    assert_fixed_budget_up_to_each_stop,
    assert_same_curves,
    budget_for,
    run_small,
    small_mdp,
)

from vdbejax import cli
from vdbejax.envs.table_cleaning import make_mdp
from vdbejax.results.grid_result import GridResult
from vdbejax.results.solving import episodes_to_converge
from vdbejax.runs import FixedBudget, RunOptions, RunState, UntilSolved, prepare_grid, run_prepared
from vdbejax.runs.checkpoint import load_checkpoint


@pytest.fixture(scope="module")
def reference():
    return run_small()


#: Until solved at half the best return, on the paper's task (some agents solve within
#: the budget, some do not).
UNTIL = {"num_episodes": 160, "chunk_episodes": 16, "stop": UntilSolved(fraction=0.5)}


def run_until(**overrides):
    return run_small(mdp=make_mdp(), **{**UNTIL, **overrides})


@pytest.fixture(scope="module")
def until():
    return run_until()


@pytest.mark.parametrize("field, value, match", [
    ("chunk_episodes", 0, "chunk_episodes=0 is invalid"),
    ("progress", "yes", "progress='yes' is invalid"),
    ("resume", 1, "resume=1 is invalid"),
    ("memory_budget_bytes", "lots", "memory_budget_bytes='lots' is invalid"),
    ("devices", 0, "devices=0 is invalid"),
    ("strategy", "fast", "strategy='fast' is invalid"),
    ("threads", 0, "threads=0 is invalid"),
    ("stop", "solved", "stop='solved' is invalid"),
    ("checkpoint", 3, "checkpoint=3 is invalid"),
])
def test_run_options_are_checked_when_made(field, value, match):
    with pytest.raises(ValueError, match=match):
        RunOptions(**{field: value})


@pytest.mark.parametrize("kwargs, match", [
    ({"fraction": 0}, "fraction=0 is invalid"),
    ({"window": 0}, "window=0 is invalid"),
    ({"max_seconds": -1}, "max_seconds=-1 is invalid"),
    ({"best": 0, "baseline": 0}, "best=0 and baseline=0 are invalid"),
    ({"best": 1.0}, "give both"),
])
def test_stop_policies_are_checked_when_made(kwargs, match):
    with pytest.raises(ValueError, match=match):
        UntilSolved(**kwargs)


def test_an_unknown_run_option_is_one_line():
    with pytest.raises(ValueError, match="chunk is not a run option: the options are chunk_episodes"):
        run_small(chunk=3)


def test_options_object_and_keywords_are_one_thing(reference):
    run = RunOptions(chunk_episodes=5, memory_budget_bytes=budget_for(small_mdp(), 4, 8))
    whole = run_small(run=run, chunk_episodes=8)  # keywords apply over the object
    assert whole.meta["batches"] == 3
    assert_same_curves(whole, reference)


def test_the_plan_is_stated_in_meta(reference):
    plan = reference.meta["plan"]
    assert plan["devices"] == 1 and plan["processes"] == 1 and plan["sharded"] is False
    assert plan["strategy"] in ("sequential", "lockstep") and plan["compact"] is True
    assert reference.meta["stop"] == {"policy": "fixed_budget"}
    lockstep = run_small(strategy="lockstep")
    assert lockstep.meta["plan"]["strategy"] == lockstep.meta["strategy"] == "lockstep"
    assert lockstep.meta["plan"]["strategy_rule"] == "asked"
    assert lockstep.meta["plan"]["mix_kinds"] is False  # kind after kind on a CPU
    assert plan["strategy_rule"].startswith("auto: cpu, ")  # the rule and the agents it saw
    assert_same_curves(lockstep, reference)


def test_prepare_checks_everything_and_creates_nothing(tmp_path):
    folder = tmp_path / "never"
    with pytest.raises(ValueError, match="num_seeds=0 is invalid"):
        prepare_grid(small_mdp(), SETTINGS, num_seeds=0,
                     run=RunOptions(checkpoint=folder / "c.npz"))
    assert not folder.exists()
    prepared = prepare_grid(small_mdp(), SETTINGS, num_seeds=SEEDS, num_episodes=EPISODES,
                            seed=3, run=RunOptions(chunk_episodes=8))
    assert prepared.num_agents == len(SETTINGS) * SEEDS
    assert_same_curves(run_prepared(prepared), run_small())


def test_until_solved_equals_the_fixed_budget_up_to_each_stop(until):
    fixed = run_small(mdp=make_mdp(), num_episodes=160, chunk_episodes=16)
    stops = until.episodes_run
    assert stops is not None and stops.shape == (len(SETTINGS), SEEDS)
    assert (stops < 160).any() and (stops == 160).any()
    assert (stops % 16 == 0).all()  # agents leave at a chunk's end
    stop = until.meta["stop"]
    solve = episodes_to_converge(until.returns, stop["best"], stop["baseline"], fraction=0.5,
                                 episodes_run=stops)
    np.testing.assert_array_equal(solve.solved[stops < 160], True)
    assert_fixed_budget_up_to_each_stop(until, fixed, stops)
    assert until.meta["stopped"] == "episodes"  # some agent ran the whole budget
    assert until.meta["fingerprint"] != fixed.meta["fingerprint"]  # the policy is part of it


def test_until_solved_in_batches_equals_one_batch(until):
    batched = run_until(memory_budget_bytes=budget_for(make_mdp(), 4, chunk_episodes=16))
    assert batched.meta["plan"]["agents_per_batch"] == 4
    np.testing.assert_array_equal(batched.episodes_run, until.episodes_run)
    assert_same_curves(batched, until)


def test_a_time_budget_stops_every_remaining_agent():
    until = run_small(num_episodes=48, stop=UntilSolved(fraction=1.0, max_seconds=1e-9))
    assert until.meta["stopped"] == "seconds"
    assert (until.episodes_run == 8).all()  # one chunk, then out of time


class Interrupted(Exception):
    pass


def interrupt_after(calls: int):
    seen = []

    def progress(done, total, elapsed):
        seen.append(done)
        if len(seen) == calls:
            raise Interrupted

    return progress


def test_until_solved_resumes_bit_identically_with_stopped_agents(tmp_path, until):
    checkpoint = tmp_path / "ckpt.npz"
    prepared = prepare_grid(make_mdp(), SETTINGS, num_seeds=SEEDS, num_episodes=160, seed=3,
                            run=RunOptions(chunk_episodes=16, stop=UntilSolved(fraction=0.5),
                                           checkpoint=checkpoint, progress=interrupt_after(8)))
    with pytest.raises(Interrupted):  # start, then 7 chunks: some agents have stopped
        run_prepared(prepared)
    state, _, _ = load_checkpoint(checkpoint, prepared.fingerprint, (prepared.num_agents, 160))
    assert isinstance(state, RunState) and state.stopped.any() and not state.finished.all()
    assert not np.isin(state.state_rows, np.flatnonzero(state.stopped)).any()
    resumed = run_until(checkpoint=checkpoint, resume=True)
    assert resumed.meta["resumed_from_agent_episodes"] > 0
    np.testing.assert_array_equal(resumed.episodes_run, until.episodes_run)
    assert_same_curves(resumed, until)


def test_an_until_solved_result_saves_and_loads(tmp_path, until):
    until.save(tmp_path)
    loaded = GridResult.load(tmp_path)
    np.testing.assert_array_equal(loaded.episodes_run, until.episodes_run)
    assert_same_curves(loaded, until)
    assert run_small().episodes_run is None  # a fixed budget: every episode ran


def test_fixed_budget_is_the_default():
    assert RunOptions().stop == FixedBudget()


def test_every_training_command_takes_the_run_flags():
    parser = cli.build_parser()
    for command in ("reproduce", "run", "scale", "ablate"):
        args = parser.parse_args([command, "--out", "x", "--resume", "--devices", "1",
                                  "--memory-budget", "64M"])
        assert (args.resume, args.devices, args.memory_budget) == (True, 1, "64M"), command


def sweep_args(out):
    return ["run", "--out", str(out), "--learners", "qlearning", "--explorers", "egreedy,vdbe",
            "--seeds", "2", "--episodes", "30", "--chunk-episodes", "10", "--quiet",
            "--no-figures"]


def test_a_stop_before_the_first_checkpoint_says_there_is_nothing_to_resume(
        tmp_path, monkeypatch, capsys):
    from vdbejax.runs import grid

    def stopped(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(grid, "drive", stopped)
    out = tmp_path / "sweep"
    assert cli.main(sweep_args(out)) == 130
    err = capsys.readouterr().err
    assert err.strip() == "interrupted: no checkpoint was written yet, a rerun starts from the" \
        " beginning", err
    assert not (out / "checkpoint.npz").exists()


def test_run_resumes_from_its_checkpoint(tmp_path, monkeypatch, capsys):
    out = tmp_path / "sweep"
    assert cli.main(sweep_args(tmp_path / "whole")) == 0
    whole = GridResult.load(tmp_path / "whole")
    from vdbejax.runs import driver

    real = driver.drive
    seen = []

    def interrupted_drive(*args, **kwargs):
        progress = kwargs["progress"]

        def stop_after_two(done, total, elapsed):
            seen.append(done)
            if len(seen) == 3:
                raise KeyboardInterrupt
            if progress is not None:
                progress(done, total, elapsed)

        kwargs["progress"] = stop_after_two
        return real(*args, **kwargs)

    from vdbejax.runs import grid

    monkeypatch.setattr(grid, "drive", interrupted_drive)
    assert cli.main(sweep_args(out)) == 130
    assert "rerun with --resume" in capsys.readouterr().err
    assert (out / "checkpoint.npz").exists() and not (out / "returns.npz").exists()
    monkeypatch.setattr(grid, "drive", real)
    assert cli.main([*sweep_args(out), "--resume"]) == 0
    resumed = GridResult.load(out)
    assert resumed.meta["resumed_from_agent_episodes"] > 0
    assert not (out / "checkpoint.npz").exists()
    assert_same_curves(resumed, whole)
    # A whole result of the same run is reused, not trained again.
    before = (out / "meta.json").read_text()
    assert cli.main([*sweep_args(out), "--resume"]) == 0
    assert json.loads((out / "meta.json").read_text()) == json.loads(before)


def test_run_flags_reach_the_run(tmp_path):
    out = tmp_path / "sweep"
    from vdbejax.studies.task_names import make_task

    budget = budget_for(make_task("table_cleaning"), 2, chunk_episodes=10)
    assert cli.main([*sweep_args(out), "--memory-budget", str(budget), "--devices", "1"]) == 0
    meta = GridResult.load(out).meta
    assert meta["plan"]["devices"] == 1 and meta["plan"]["agents_per_batch"] == 2
    assert meta["batches"] == 2  # 4 agents, 2 at a time


@pytest.mark.parametrize("command", ["run", "scale", "reproduce"])
def test_bad_run_flags_fail_in_one_line_before_training(tmp_path, capsys, command):
    out = tmp_path / "bad"
    args = (sweep_args(out) if command == "run" else [command, "--out", str(out), "--quiet"])
    assert cli.main([*args, "--devices", "1000"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: devices=1000 is invalid") and len(err.splitlines()) == 1
    assert not (out / "returns.npz").exists() and not (out / "checkpoint.npz").exists()


@pytest.mark.parametrize("module,function,field", [
    ("vdbejax.studies.sweeps", "run_sweep", "checkpoint"),
    ("vdbejax.studies.scaling", "run_scaling", "evaluate_every"),
    ("vdbejax.studies.bench", "run_bench", "chunk_episodes"),
    ("vdbejax.studies.depth", "run_depth", "stop"),
    ("vdbejax.paper.reproduce", "reproduce", "record_optimal"),
    ("vdbejax.paper.ablation", "ablate", "evaluate_every"),
    ("vdbejax.studies.scaling_adaptive", "run_until_solved", "stop"),
])
def test_a_study_refuses_a_run_option_it_does_not_take(tmp_path, module, function, field):
    # Every study takes its run mechanics as one RunOptions; a field it would ignore (the
    # folder's checkpoint, a stop or a chunk it sets itself, …) fails in one line, first.
    import importlib

    from vdbejax.studies.sweeps import Sweep

    value = {"checkpoint": tmp_path / "c.npz", "evaluate_every": 10, "chunk_episodes": 10,
             "stop": UntilSolved(), "record_optimal": True}[field]
    out = tmp_path / "out"
    first = {"run_sweep": (out, Sweep(learners=["qlearning"], explorers=["egreedy"])),
             "run_until_solved": (make_mdp(), [])}.get(function, (out,))
    size = {"run_until_solved": {"num_seeds": 1, "max_episodes": 1}}.get(function, {})
    study = getattr(importlib.import_module(module), function)
    with pytest.raises(ValueError, match=rf"^run\.{field}=.* {function} does not take it"):
        study(*first, **size, run=RunOptions(**{field: value}))
    assert not out.exists()


def test_the_plan_sizes_chunks_by_agent_episodes_and_results_do_not_change():
    from small_grid import SETTINGS, run_small

    from vdbejax.runs.plan import (
        CHUNK_EPISODES_MAX,
        CHUNK_EPISODES_MIN,
        default_chunk_episodes,
    )

    assert default_chunk_episodes(46 * 20, 1000) == 100  # the paper grid's chunks
    assert default_chunk_episodes(46 * 100, 1000) == CHUNK_EPISODES_MIN
    assert default_chunk_episodes(1, 10**7) == CHUNK_EPISODES_MAX  # one agent, many episodes
    assert default_chunk_episodes(4, 600) == 600  # a short run: one chunk
    calls = []
    planned = run_small(num_episodes=120, chunk_episodes=None,
                        progress=lambda done, total, t: calls.append(done))
    # 12 agents: a chunk of up to all 120 episodes, cut by time (vdbejax.engine.chunks):
    # the first chunk is one episode, the next ones at most four times the previous.
    agents = len(SETTINGS) * 3
    assert calls[:2] == [0, agents] and calls[-1] == agents * 120, calls
    episodes = np.diff(calls) // agents
    assert (episodes[1:] <= 4 * episodes[:-1]).all(), calls
    chunked = run_small(num_episodes=120, chunk_episodes=7)
    assert (planned.returns == chunked.returns).all()
    assert (planned.lengths == chunked.lengths).all()
