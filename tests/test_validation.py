"""Every invalid input is rejected with one line naming the parameter, the value and what
is allowed (library: ValueError; CLI: exit status 2, no traceback), and NaN/inf appearing
during a run is reported with the configuration that produced it."""
from __future__ import annotations

import subprocess
import sys
import warnings

import numpy as np
import pytest
from small_grid import SETTINGS, run_small

from vdbejax import cli, make_tabular_mdp
from vdbejax.envs.suite import make_suite_task
from vdbejax.envs.table_cleaning import make_mdp
from vdbejax.methods.agents import AgentOptions, Setting, make_agent
from vdbejax.methods.explorers import make_explorer
from vdbejax.methods.learners import make_learner
from vdbejax.results.grid_result import GridResult
from vdbejax.runs import run_grid


def assert_one_line(error: pytest.ExceptionInfo, *fragments: str) -> None:
    message = str(error.value)
    assert "\n" not in message, message
    for fragment in fragments:
        assert fragment in message, (fragment, message)


NAN, INF = float("nan"), float("inf")

# (parameter, value, expected fragment of "allowed")
LEARNER_CASES = [
    ("alpha", 0.0, "(0, 1]"), ("alpha", 1.5, "(0, 1]"), ("alpha", -0.1, "(0, 1]"),
    ("alpha", NAN, "(0, 1]"), ("alpha", INF, "(0, 1]"), ("alpha", "0.5", "number"),
    ("alpha", None, "number"), ("alpha", True, "number"),
    ("gamma", -0.1, "[0, 1]"), ("gamma", 1.01, "[0, 1]"), ("gamma", NAN, "[0, 1]"),
    ("gamma", INF, "[0, 1]"),
    ("q_init", NAN, "finite"), ("q_init", INF, "finite"), ("q_init", -INF, "finite"),
    ("q_init", "zero", "finite"),
]


@pytest.mark.parametrize("name, value, allowed", LEARNER_CASES)
def test_learner_parameters(name, value, allowed):
    kwargs = {"alpha": 0.8, "gamma": 0.9, "q_init": 0.0, name: value}
    with pytest.raises(ValueError) as error:
        make_learner("qlearning", **kwargs)
    assert_one_line(error, f"{name}=", "is invalid", allowed)


EXPLORER_CASES = [
    ("egreedy", "epsilon", -0.01), ("egreedy", "epsilon", 1.01), ("egreedy", "epsilon", NAN),
    ("egreedy", "epsilon", INF), ("egreedy", "epsilon", "a"),
    ("softmax", "tau", 0.0), ("softmax", "tau", -1.0), ("softmax", "tau", NAN),
    ("softmax", "tau", INF),
    ("vdbe", "sigma", 0.0), ("vdbe", "sigma", -1.0), ("vdbe", "sigma", NAN), ("vdbe", "sigma", INF),
    ("vdbe_softmax", "sigma", 0.0), ("vdbe_softmax", "sigma", NAN),
]


@pytest.mark.parametrize("explorer, name, value", EXPLORER_CASES)
def test_explorer_parameters(explorer, name, value):
    with pytest.raises(ValueError) as error:
        make_explorer(explorer, value)
    assert_one_line(error, f"{name}=", "is invalid")


@pytest.mark.parametrize("delta", [0.0, -0.5, 1.5, NAN, INF])
def test_vdbe_delta(delta):
    with pytest.raises(ValueError) as error:
        make_explorer("vdbe", 1.0, delta=delta)
    assert_one_line(error, "delta=", "(0, 1]")


@pytest.mark.parametrize("tau", [0.0, -1.0, NAN, INF])
def test_vdbe_softmax_tau(tau):
    with pytest.raises(ValueError) as error:
        make_explorer("vdbe_softmax", 1.0, tau=tau)
    assert_one_line(error, "tau=", "> 0")


def test_unknown_names():
    with pytest.raises(ValueError) as error:
        make_agent(Setting("td_lambda", "egreedy", 0.1))
    assert_one_line(error, "learner='td_lambda'", "qlearning", "sarsa")
    with pytest.raises(ValueError) as error:
        make_agent(Setting("qlearning", "ucb", 0.1))
    assert_one_line(error, "explorer='ucb'", "egreedy", "vdbe_softmax")
    with pytest.raises(ValueError) as error:
        make_agent(SETTINGS[0], AgentOptions(tie_break="last"))
    assert_one_line(error, "tie_break='last'", "random", "first")


@pytest.mark.parametrize("call, nearest", [
    (lambda: make_agent(Setting("qlearning", "vdbe_sofmax", 0.1)), "vdbe_softmax"),
    (lambda: make_agent(Setting("qlearnin", "egreedy", 0.1)), "qlearning"),
    (lambda: make_suite_task("riverswm"), "riverswim"),
    (lambda: make_suite_task("chian:8"), "chain:8"),
])
def test_a_typo_gets_the_nearest_names(call, nearest):
    with pytest.raises(ValueError) as error:
        call()
    assert_one_line(error, "must be one of", f"(did you mean {nearest}")
    # a name near nothing gets the list alone
    with pytest.raises(ValueError) as error:
        make_agent(Setting("qlearning", "zzzz", 0.1))
    assert "did you mean" not in str(error.value)


def test_cli_typo_and_learners_without_explorers_say_what_to_change(tmp_path, capsys):
    out = tmp_path / "out"
    run = ["run", "--out", str(out), "--task", "chain", "--seeds", "1", "--episodes", "2",
           "--quiet"]
    assert cli.main(run + ["--learners", "qlearning", "--explorers", "vdbe_sofmax"]) == 2
    assert "did you mean vdbe_softmax" in capsys.readouterr().err
    assert cli.main(run + ["--task", "riverswm", "--learners", "qlearning", "--explorers",
                           "egreedy"]) == 2
    assert "task='riverswm' is invalid" in capsys.readouterr().err
    assert cli.main(run + ["--learners", "qlearning",
                           "--setting", "learner=qlearning,explorer=egreedy,epsilon=0.1"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: explorers is missing: learners=['qlearning']") and \
        "give --explorers" in err and "leave out learners" in err and len(err.splitlines()) == 1
    assert not out.exists()


RUN_GRID_CASES = [
    ("num_seeds", 0, ">= 1"), ("num_seeds", -2, ">= 1"), ("num_seeds", 1.5, "integer"),
    ("num_seeds", "3", "integer"), ("num_seeds", True, "integer"), ("num_seeds", NAN, "integer"),
    ("num_episodes", 0, ">= 1"), ("num_episodes", INF, "integer"),
    ("seed", -1, ">= 0"), ("seed", 0.5, "integer"),
    ("chunk_episodes", 0, ">= 1"),
    ("resume", "yes", "True or False"),
    ("memory_budget_bytes", 0, "size in bytes"), ("memory_budget_bytes", "lots", "size in bytes"),
    ("memory_budget_bytes", 100, "one agent needs"),
    ("devices", 0, ">= 1"), ("devices", 1000, "device(s) available"),
    ("progress", "yes", "callable"), ("checkpoint", 3, "file path"),
]


@pytest.mark.parametrize("name, value, allowed", RUN_GRID_CASES)
def test_run_grid_arguments(name, value, allowed):
    with pytest.raises(ValueError) as error:
        run_small(**{name: value})
    assert_one_line(error, f"{name}=", "is invalid", allowed)


def test_run_grid_unwritable_checkpoint_folder_fails_before_training(tmp_path):
    blocker = tmp_path / "a_file"
    blocker.write_text("")
    with pytest.raises(ValueError) as error:
        run_small(checkpoint=blocker / "ckpt.npz")
    assert_one_line(error, "checkpoint folder=", "must be a writable folder")


def test_run_grid_settings_and_mdp():
    mdp = make_mdp(max_steps=5)
    with pytest.raises(ValueError) as error:
        run_grid(mdp, [])
    assert_one_line(error, "settings is empty")
    with pytest.raises(ValueError) as error:
        run_grid(mdp, [("qlearning", "egreedy", 0.1)])
    assert_one_line(error, "settings holds", "Setting(")
    with pytest.raises(ValueError) as error:
        run_grid({"next_state": [[0]]}, SETTINGS)
    assert_one_line(error, "mdp=dict", "TabularMDP")


@pytest.mark.parametrize("kwargs, fragment", [
    (dict(max_steps=0), "max_steps=0"), (dict(max_steps=-3), "max_steps=-3"),
    (dict(max_steps=2.5), "max_steps=2.5"), (dict(invalid_action="crash"), "invalid_action='crash'"),
])
def test_table_cleaning_options(kwargs, fragment):
    with pytest.raises(ValueError) as error:
        make_mdp(**kwargs)
    assert_one_line(error, fragment, "is invalid")


def good_mdp_arrays():
    """A 2-state chain: state 0 --a0--> 0, --a1--> 1 (terminal)."""
    return dict(next_state=np.array([[0, 1], [1, 1]]), reward=np.array([[0.0, 1.0], [0.0, 0.0]]),
                terminal=np.array([False, True]), start_probability=np.array([1.0, 0.0]))


@pytest.mark.parametrize("change, fragment", [
    (dict(next_state=np.array([[0, 2], [1, 1]])), "next_state"),        # index out of range
    (dict(next_state=np.array([[0, -1], [1, 1]])), "next_state"),       # negative index
    (dict(next_state=np.array([0, 1])), "next_state"),                  # wrong rank
    (dict(next_state=np.array([[0.0, 1.0], [1.0, 1.0]])), "next_state"),  # not integers
    (dict(reward=np.array([[0.0, NAN], [0.0, 0.0]])), "reward"),
    (dict(reward=np.array([[0.0, INF], [0.0, 0.0]])), "reward"),
    (dict(reward=np.zeros((3, 2))), "reward"),                          # wrong shape
    (dict(terminal=np.zeros((3, 3), bool)), "terminal"),
    (dict(start_probability=np.array([0.5, 0.4])), "start_probability"),  # sums to 0.9
    (dict(start_probability=np.array([1.5, -0.5])), "start_probability"),  # negative
    (dict(start_probability=np.array([1.0])), "start_probability"),    # wrong length
    (dict(start_probability=np.array([NAN, 1.0])), "start_probability"),
    (dict(probability=np.array([[0.5], [1.0]])), "probability"),       # wrong shape
    (dict(next_state=np.array([[[0, 1]], [[1, 1]]]),                   # probabilities sum to 0.9
          reward=np.zeros((2, 1, 2)), terminal=np.zeros((2, 1, 2), bool),
          probability=np.array([[[0.5, 0.4]], [[1.0, 0.0]]])), "probability"),
    (dict(max_steps=0), "max_steps"),
])
def test_make_tabular_mdp_rejects_malformed_arrays(change, fragment):
    arrays = dict(good_mdp_arrays(), **change)
    with pytest.raises(ValueError) as error:
        make_tabular_mdp(**arrays)
    assert_one_line(error, fragment)


def test_make_tabular_mdp_accepts_the_good_arrays():
    mdp = make_tabular_mdp(**good_mdp_arrays())
    assert mdp.num_states == 2 and mdp.num_actions == 2


# ---------------------------------------------------------------------------- CLI
BASE = ["reproduce", "--seeds", "1", "--episodes", "2", "--max-steps", "5", "--quiet"]

CLI_CASES = [
    (["--seeds", "abc"], "seeds='abc' is invalid"), (["--seeds", "nan"], "seeds=nan is invalid"),
    (["--seeds", "inf"], "seeds=inf is invalid"), (["--seeds", "-3"], "seeds=-3 is invalid"),
    (["--seeds", "0"], "seeds=0 is invalid"), (["--seeds", "1.5"], "seeds=1.5 is invalid"),
    (["--episodes", "0"], "episodes=0 is invalid"), (["--episodes", "x"], "episodes='x' is invalid"),
    (["--episodes", "-1"], "episodes=-1 is invalid"), (["--episodes", "nan"], "episodes=nan"),
    (["--seed", "-1"], "seed=-1 is invalid: must be an integer >= 0"),
    (["--seed", "1e3"], "seed=1000.0 is invalid"),
    (["--max-steps", "0"], "max_steps=0 is invalid"), (["--max-steps", "inf"], "max_steps=inf"),
    (["--max-steps", "ten"], "max_steps='ten' is invalid"),
    (["--q-init", "nan"], "q_init=nan is invalid: must be a finite number"),
    (["--q-init", "inf"], "q_init=inf is invalid"), (["--q-init=-inf"], "q_init=-inf"),  # "=": argparse reads a lone -inf as an option
    (["--q-init", "zero"], "q_init='zero' is invalid"),
    (["--tie-break", "last"], "tie_break='last' is invalid: must be one of random, first"),
    (["--invalid-action", "crash"], "invalid_action='crash' is invalid: must be one of noop, fail"),
    (["--chunk-episodes", "0"], "chunk_episodes=0 is invalid"),
    (["--chunk-episodes", "2.5"], "chunk_episodes=2.5 is invalid"),
    (["--memory-budget", "0"], "memory_budget_bytes='0' is invalid"),
    (["--memory-budget", "lots"], "memory_budget_bytes='lots' is invalid"),
    (["--memory-budget=-1G"], "memory_budget_bytes='-1G' is invalid"),
    (["--memory-budget", "100"], "one agent needs about"),
    (["--devices", "0"], "devices=0 is invalid"), (["--devices", "999"], "devices=999 is invalid"),
    (["--devices", "two"], "devices='two' is invalid"),
]


@pytest.mark.parametrize("args, message", CLI_CASES)
def test_cli_bad_option_exits_2_with_one_line(tmp_path, capsys, args, message):
    status = cli.main(BASE + ["--out", str(tmp_path / "out")] + args)
    captured = capsys.readouterr()
    assert status == 2
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and message in lines[0], captured.err
    assert "Traceback" not in captured.err


def test_cli_unwritable_out(tmp_path, capsys):
    blocker = tmp_path / "a_file"
    blocker.write_text("")
    status = cli.main(BASE + ["--out", str(blocker / "out")])
    err = capsys.readouterr().err
    assert status == 2
    assert err.strip().startswith("error: out=") and "must be a writable folder" in err
    assert len(err.strip().splitlines()) == 1


def test_cli_bad_input_in_a_real_process_prints_no_traceback(tmp_path):
    done = subprocess.run([sys.executable, "-m", "vdbejax", *BASE, "--out", str(tmp_path),
                           "--seeds", "nan"], capture_output=True, text=True, timeout=120)
    assert done.returncode == 2
    assert done.stderr.strip() == ("error: seeds=nan is invalid: must be an integer >= 1"
                                   " and <= 2147483647")


# ---------------------------------------------------------------------- NaN / inf
def overflowing_mdp():
    """A state whose self-loop pays 3e38: with q_init 3e38 the target overflows to inf."""
    return make_tabular_mdp(np.array([[0, 1], [1, 1]]), np.array([[3e38, 0.0], [0.0, 0.0]]),
                            np.array([False, True]), np.array([1.0, 0.0]), max_steps=5,
                            name="overflow")


def test_nonfinite_values_are_reported_with_their_config(tmp_path):
    settings = [Setting("qlearning", "egreedy", 0.1), Setting("sarsa", "vdbe", 1.0)]
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        result = run_grid(overflowing_mdp(), settings, num_seeds=2, num_episodes=3,
                          options=AgentOptions(q_init=3e38))
    assert result.nonfinite[0].all()
    messages = [str(w.message) for w in caught if issubclass(w.category, RuntimeWarning)]
    assert any("NaN or inf appeared in Q or ε, or an invalid action was drawn, for: qlearning/egreedy/epsilon=0.1 (2/2 agents)" in m
               and "'q_init': 3e+38" in m for m in messages), messages
    assert result.meta["nonfinite_agents"] == int(result.nonfinite.sum())
    assert "qlearning/egreedy/epsilon=0.1" in result.meta["nonfinite_message"]
    result.save(tmp_path)
    loaded = GridResult.load(tmp_path)
    np.testing.assert_array_equal(loaded.nonfinite, result.nonfinite)
    assert loaded.meta["nonfinite_message"] == result.meta["nonfinite_message"]


def test_finite_run_reports_nothing():
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        result = run_small()
    assert result.meta["nonfinite_agents"] == 0 and result.meta["nonfinite_message"] is None


def test_cli_prints_the_nonfinite_configs(tmp_path, capsys, monkeypatch):
    # `vdbejax.paper.reproduce` the attribute is the function; patch the module's task factory.
    reproduce_module = sys.modules["vdbejax.paper.reproduce"]
    monkeypatch.setattr(reproduce_module, "make_mdp", lambda **options: overflowing_mdp())
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        status = cli.main(["reproduce", "--out", str(tmp_path), "--seeds", "1", "--episodes", "3",
                           "--q-init", "3e38", "--quiet"])
    assert status == 0
    err = capsys.readouterr().err
    assert "warning: NaN or inf appeared in Q or ε, or an invalid action was drawn, for: qlearning/egreedy/epsilon=0.01" in err
    assert GridResult.load(tmp_path).meta["nonfinite_agents"] > 0
    from vdbejax.results import io

    summary = io.read_csv(tmp_path / "summary.csv")
    assert int(summary[0]["nonfinite_agents"]) == 1  # the summary shows it per config


# ------------------------------------------------------------- NaN action weights
def test_nan_or_vanishing_action_weights_are_flagged_not_hidden():
    # An unstabilised softmax (the authors' formula, here in float32): with τ = 1e-4 every
    # weight underflows to 0 once all Q values are below ≈ −0.01, and a positive Q
    # overflows to inf. Either way the draw is no distribution, and the agents must be
    # flagged (nonfinite), not silently take some action.
    import jax.numpy as jnp

    from vdbejax.methods import Explorer, explorer, sample_categorical

    @explorer("raw_softmax_test", parameter="tau")
    class RawSoftmax(Explorer):
        tau: float = 1e-4
        num_uniforms = 2

        def select(self, q, tables, context, uniforms):
            return sample_categorical(jnp.exp(q / self.tau), uniforms[0])

    assert int(sample_categorical(jnp.array([jnp.nan, 1.0]), jnp.float32(0.5))) == 2
    assert int(sample_categorical(jnp.zeros(3), jnp.float32(0.5))) == 3
    assert int(sample_categorical(jnp.full((40,), jnp.nan), jnp.float32(0.5))) == 40  # cumsum path
    assert int(sample_categorical(jnp.array([0.0, jnp.inf]), jnp.float32(0.5))) == 2
    assert int(sample_categorical(jnp.array([0.0, 2.0]), jnp.float32(0.5))) == 1
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        result = run_grid(make_mdp(max_steps=20), [Setting("qlearning", "raw_softmax_test", 1e-4),
                                        Setting("qlearning", "egreedy", 0.1)],
                          num_seeds=3, num_episodes=30)
    assert result.nonfinite[0].all() and not result.nonfinite[1].any()
    assert "raw_softmax_test" in result.meta["nonfinite_message"]
