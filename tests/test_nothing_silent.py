"""Mistakes that used to pass without a word (issue "Nothing silent"): each is now refused
in one line, before anything trains, or cleaned up."""
from __future__ import annotations

import jax.numpy as jnp
import numpy as np
import pytest

from vdbejax import cli
from vdbejax.envs.table_cleaning import make_mdp
from vdbejax.methods import Explorer, Learner, LearnerUpdate, Setting, explorer, learner
from vdbejax.methods.agents import AgentOptions
from vdbejax.paper.reproduce import reproduce
from vdbejax.results.folder_lock import MARKER_FILE, FolderLock, mark
from vdbejax.runs import RunOptions, run_grid
from vdbejax.studies import scaling, scaling_report
from vdbejax.validation import check_int


def sweep_args(out, *extra):
    return ["run", "--out", str(out), "--learners", "qlearning", "--explorers", "egreedy",
            "--seeds", "2", "--episodes", "10", "--quiet", *extra]


def refused_before_training(setting: Setting, match: str) -> None:
    """A one-agent, two-episode run of ``setting`` is refused with ``match``."""
    with pytest.raises(ValueError, match=match):
        run_grid(make_mdp(), [setting], num_seeds=1, num_episodes=2)


def one_error_line(capsys) -> str:
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), lines
    return lines[0]


def test_a_rerun_without_resume_keeps_an_interrupted_runs_checkpoint(tmp_path, capsys):
    out = tmp_path / "run"
    out.mkdir()
    (out / "checkpoint.npz").write_bytes(b"an interrupted run's progress")
    assert cli.main(sweep_args(out)) == 2
    line = one_error_line(capsys)
    assert "checkpoint of an interrupted run" in line and "--resume" in line
    assert (out / "checkpoint.npz").read_bytes() == b"an interrupted run's progress"
    assert not (out / "returns.npz").exists()


def test_outputs_of_an_earlier_run_do_not_survive_a_rerun(tmp_path):
    out = tmp_path / "run"
    assert cli.main(sweep_args(out, "--long-csv")) == 0
    assert (out / "fig3.png").exists() and (out / "returns_long.csv").exists()
    assert cli.main(sweep_args(out, "--no-figures", "--episodes", "12", "--overwrite")) == 0
    assert not (out / "fig3.png").exists() and not (out / "sensitivity.png").exists()
    assert not (out / "returns_long.csv").exists()  # it described the earlier run


def test_scale_locks_its_folder_and_a_half_written_study_is_refused(tmp_path):
    out = tmp_path / "scale"
    out.mkdir()
    with FolderLock(out), pytest.raises(ValueError, match="is being written by another"):
        scaling.run_scaling(out, size=scaling.QUICK, run=RunOptions(progress=False))
    (out / "scaling.csv").write_text("size\n")
    (out / "meta.json").write_text("{}")
    mark(out, "results")
    with pytest.raises(ValueError, match=f"half-written.*{MARKER_FILE}"):
        scaling_report.load_scaling(out)


def test_a_plug_in_cannot_take_a_built_ins_name():
    with pytest.raises(ValueError, match="explorer name 'egreedy' is a built-in's"):
        @explorer("egreedy", parameter="epsilon")
        class Impostor(Explorer):
            epsilon: float = 0.1

            def select(self, q, tables, context, uniforms):
                return jnp.argmax(q)

    for _ in range(2):  # the same definition run again (a notebook cell) replaces itself
        @explorer("nothing_silent_mine")
        class Mine(Explorer):
            def select(self, q, tables, context, uniforms):
                return jnp.argmax(q)

    with pytest.raises(ValueError, match="explorer name 'nothing_silent_mine' is taken by"):
        @explorer("nothing_silent_mine")
        class Other(Explorer):
            def select(self, q, tables, context, uniforms):
                return jnp.argmin(q)

    @explorer("nothing_silent_mine", replace=True)
    class Replacement(Explorer):
        def select(self, q, tables, context, uniforms):
            return jnp.argmin(q)


@pytest.mark.parametrize("value", [np.array(2.7), np.float64(2.0), 2.0])
def test_a_float_count_is_not_cut_to_an_integer(value):
    with pytest.raises(ValueError, match="num_seeds=2.* is invalid: must be an integer"):
        check_int("num_seeds", value)
    with pytest.raises(ValueError, match="num_seeds=2.* is invalid"):
        run_grid(make_mdp(), [Setting("qlearning", "egreedy", 0.1)], num_seeds=value,
                 num_episodes=2)
    assert check_int("num_seeds", np.array(3)) == 3


def test_an_unknown_detail_is_refused_before_the_folder_exists(tmp_path):
    with pytest.raises(ValueError, match="details has 'nosuch': no learner or explorer"):
        reproduce(tmp_path / "never", details={"nosuch": 1}, run=RunOptions(progress=False))
    assert not (tmp_path / "never").exists()


@learner("nothing_silent_int_q")
class _IntegerQ(Learner):
    gamma: float = 0.9

    def update(self, t):
        new = jnp.round(t.q).astype(jnp.int32)  # Q stored as integers: learning rounded away
        return LearnerUpdate(new, {}, new - t.q)


def test_a_learner_returning_integer_q_values_is_refused():
    with pytest.raises(ValueError, match="update\\(\\) q returned .*int32.*expected .*float32"):
        run_grid(make_mdp(), [Setting("nothing_silent_int_q", "egreedy", 0.1)], num_seeds=1,
                 num_episodes=2, options=AgentOptions())


@learner("nothing_silent_expected_undeclared")
class _UndeclaredProbabilities(Learner):  # Expected SARSA without uses_next_probabilities
    gamma: float = 0.9
    alpha: float = 0.5

    def update(self, t):
        target = t.reward + t.discount * jnp.sum(t.next_probabilities * t.q_next)
        delta = self.alpha * (target - t.q)
        return LearnerUpdate(t.q + delta, {}, delta)


@learner("nothing_silent_sarsa_undeclared")
class _UndeclaredAction(Learner):  # SARSA without uses_next_action
    gamma: float = 0.9

    def update(self, t):
        target = t.reward + t.discount * t.q_next[t.next_action]
        return LearnerUpdate(target, {}, target - t.q)


@pytest.mark.parametrize("name, field, flag", [
    ("nothing_silent_expected_undeclared", "next_probabilities", "uses_next_probabilities"),
    ("nothing_silent_sarsa_undeclared", "next_action", "uses_next_action"),
])
def test_a_learner_reading_what_it_did_not_declare_is_refused(name, field, flag):
    with pytest.raises(ValueError, match=f"reads t.{field} but the learner does not declare"
                                         f" {flag} = True"):
        run_grid(make_mdp(), [Setting(name, "softmax", 0.1)], num_seeds=1, num_episodes=2)


def test_no_lock_file_stays_after_a_run_or_a_refusal(tmp_path, capsys):
    out = tmp_path / "run"
    assert cli.main(sweep_args(out, "--no-figures")) == 0
    assert not (out / ".vdbejax.lock").exists()
    (out / "checkpoint.npz").write_bytes(b"x")  # refused: an interrupted run's checkpoint
    assert cli.main(sweep_args(out)) == 2
    assert not (out / ".vdbejax.lock").exists()
    assert cli.main(["plot", "--results", str(out)]) == 0
    assert not (out / ".vdbejax.lock").exists()


def test_an_ablation_refused_by_its_first_variant_leaves_no_folder(tmp_path, capsys):
    # A memory budget below one agent is known only once a variant plans its run: the
    # empty folders ablate made for the document and the results are removed again.
    out, results = tmp_path / "ab", tmp_path / "raw"
    args = ["ablate", "--variants", "spec", "--memory-budget", "1", "--seeds", "2",
            "--episodes", "10", "--replicates", "1"]
    assert cli.main([*args, "--out", str(out)]) == 2
    assert "memory_budget_bytes=1 is invalid" in one_error_line(capsys)
    assert cli.main([*args, "--out", str(out), "--results", str(results)]) == 2
    assert not out.exists() and not results.exists()
    kept = tmp_path / "kept"
    (kept / "notes").mkdir(parents=True)  # a folder that existed before stays as it was
    assert cli.main([*args, "--out", str(kept)]) == 2
    assert sorted(p.name for p in kept.iterdir()) == ["notes"]


def test_a_lock_file_deleted_during_the_run_is_noticed(tmp_path, monkeypatch, capsys):
    from vdbejax.studies import folder

    out = tmp_path / "run"
    real = folder.run_prepared

    def delete_the_lock(prepared):
        result = real(prepared)
        (out / ".vdbejax.lock").unlink()  # as a careless user or another tool would
        return result

    monkeypatch.setattr(folder, "run_prepared", delete_the_lock)
    assert cli.main(sweep_args(out, "--no-figures")) == 2
    line = one_error_line(capsys)
    assert "lock file was deleted during the run" in line and "kept in" in line
    from vdbejax.results.grid_result import GridResult

    kept = line.split("kept in '")[1].split("'")[0]
    assert GridResult.load(kept).returns.shape == (1, 2, 10)


@pytest.mark.parametrize("kwargs, match", [
    ({"settings": Setting("qlearning", "egreedy", 0.1)}, "settings=Setting.* must be a list"),
    ({"settings": None}, "settings=None is invalid: must be a list"),
    ({"options": {"alpha": 0.5}}, "options=.* must be an AgentOptions"),
])
def test_wrong_types_at_run_grid_are_one_line(kwargs, match):
    work = {"settings": [Setting("qlearning", "egreedy", 0.1)], "num_seeds": 1,
            "num_episodes": 2, **kwargs}
    with pytest.raises(ValueError, match=match):
        run_grid(make_mdp(), **work)


def test_quick_does_not_override_the_sizes_without_a_word(tmp_path, capsys):
    assert cli.main(["scale", "--out", str(tmp_path / "s"), "--quick", "--sizes", "4x2"]) == 2
    assert "--quick sets the study's size: leave out --sizes" in one_error_line(capsys)


def test_an_axis_and_a_shared_value_of_one_name_are_refused(tmp_path, capsys):
    args = sweep_args(tmp_path / "r", "--axis", "alpha=0.1,0.5", "--set", "alpha=0.3")
    assert cli.main(args) == 2
    assert "alpha is both a sweep axis and a shared value" in one_error_line(capsys)


def test_the_parser_imports_no_jax():
    import subprocess
    import sys

    code = ("import sys; from vdbejax import cli; cli.build_parser();"
            " print(sorted(m for m in sys.modules if m == 'jax' or m.startswith('jax.'))[:3])")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=120)
    assert done.returncode == 0, done.stderr
    assert done.stdout.strip() == "[]"  # --help and --version stay fast


def test_a_window_longer_than_the_budget_is_refused(tmp_path, capsys):
    from vdbejax.runs import UntilSolved

    with pytest.raises(ValueError, match="window=50 is invalid with num_episodes=20"):
        run_grid(make_mdp(), [Setting("qlearning", "egreedy", 0.1)], num_seeds=1,
                 num_episodes=20, stop=UntilSolved(window=50))
    assert cli.main(["scale", "--out", str(tmp_path / "s"), "--window", "1000000000"]) == 2
    assert "window=1000000000 is invalid with episodes=2000" in one_error_line(capsys)


def test_an_option_the_authors_task_ignores_is_refused(tmp_path, capsys):
    args = ["run", "--out", str(tmp_path / "r"), "--task", "cruz2018", "--invalid-action",
            "fail", "--learners", "qlearning", "--explorers", "egreedy", "--quiet"]
    assert cli.main(args) == 2
    assert "invalid_action='fail' is invalid with task='cruz2018'" in one_error_line(capsys)


def test_a_printed_comparison_shows_the_intervals_that_decided_it():
    from vdbejax.results.verdicts import Estimate, estimate_text, less

    sarsa, qlearning = Estimate(-1.0739, -1.078, -1.070), Estimate(-1.0651, -1.068, -1.062)
    assert less(sarsa, qlearning) is True  # apart: printed as two disjoint intervals
    assert (estimate_text(sarsa), estimate_text(qlearning)) == ("[-1.078, -1.070]", "[-1.068, -1.062]")
    assert less(sarsa, Estimate(-1.07, -1.072, -1.068)) is None  # overlapping: undecided


def _greedy_plugin(pick):
    """The same plug-in class (one module and qualified name), its select() given."""
    @explorer("nothing_silent_edited", replace=True)
    class Edited(Explorer):
        def select(self, q, tables, context, uniforms):
            return pick(q)

    return Edited


def test_resume_after_editing_a_plug_in_is_refused(tmp_path):
    from vdbejax.runs import RunOptions, prepare_grid

    mdp, settings = make_mdp(max_steps=20), [Setting("qlearning", "nothing_silent_edited")]
    _greedy_plugin(jnp.argmax)
    first = prepare_grid(mdp, settings, num_seeds=2, num_episodes=4)
    assert prepare_grid(mdp, settings, num_seeds=2, num_episodes=4).fingerprint == (
        first.fingerprint)  # unchanged code: the same run
    assert "qlearning/nothing_silent_edited" in first.description["plugin_code"]
    # Built-ins only: the fingerprint has no plug-in code (earlier runs keep theirs).
    assert "plugin_code" not in prepare_grid(mdp, [Setting("qlearning", "vdbe", 1.0)],
                                             num_seeds=2, num_episodes=4).description

    checkpoint = tmp_path / "run.npz"
    calls = []

    def stop_after_first_chunk(done, total, elapsed):
        calls.append(done)
        if len(calls) == 2:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        run_grid(mdp, settings, num_seeds=2, num_episodes=4, run=RunOptions(
            checkpoint=checkpoint, chunk_episodes=2, progress=stop_after_first_chunk))
    assert checkpoint.exists()
    _greedy_plugin(jnp.argmin)  # the plug-in edited between the run and its resume
    assert prepare_grid(mdp, settings, num_seeds=2, num_episodes=4).fingerprint != (
        first.fingerprint)
    with pytest.raises(ValueError, match="belongs to a different run") as error:
        run_grid(mdp, settings, num_seeds=2, num_episodes=4,
                 run=RunOptions(checkpoint=checkpoint, resume=True, chunk_episodes=2))
    assert "\n" not in str(error.value)


def test_a_sweep_of_a_hundred_million_settings_is_refused_before_making_them():
    from vdbejax.methods import sweep

    values = [0.1] * 10_000  # 10⁴ × 10⁴ settings: building them used to take minutes
    with pytest.raises(ValueError, match="100,000,000 settings, more than the 1,000,000"):
        sweep(["qlearning"], ["egreedy"], {"epsilon": values, "alpha": values})


@pytest.mark.parametrize("command", ["scale", "bench"])
@pytest.mark.parametrize("option", ["--seeds", "--episodes"])
def test_a_study_too_large_to_fit_is_refused_before_its_folder_exists(tmp_path, capsys,
                                                                     command, option):
    out = tmp_path / command  # a billion seeds or episodes used to meet the OOM killer
    assert cli.main([command, "--out", str(out), option, "1000000000", "--quiet"]) == 2
    assert "need ≈" in one_error_line(capsys) and not out.exists()


class _Greedy(Explorer):  # no probabilities(): the plug-ins below change one thing each
    def select(self, q, tables, context, uniforms):
        return jnp.argmax(q)


@explorer("nothing_silent_ten_million_uniforms")
class _ManyUniforms(_Greedy):  # asks for more random numbers than any step could use
    num_uniforms = 10_000_000


def test_a_plug_in_asking_for_millions_of_uniforms_is_refused_before_tracing():
    refused_before_training(Setting("qlearning", "nothing_silent_ten_million_uniforms"),
                            "num_uniforms=10000000 is invalid: must be an integer in"
                            " \\[0, 4096\\]")


@learner("nothing_silent_wrong_initial_q")
class _WrongInitialQ(Learner):  # one state too many
    gamma: float = 0.9

    def initial_q(self, key, num_states, num_actions):
        return jnp.zeros((num_states + 1, num_actions))

    def update(self, t):
        return LearnerUpdate(t.q, {}, jnp.zeros_like(t.q))


def test_a_wrong_initial_q_names_the_learner_and_the_shape():
    # It used to say "Incompatible shapes for broadcasting: (109, 7), (108, 7)".
    refused_before_training(Setting("nothing_silent_wrong_initial_q", "egreedy", 0.1),
                            "learner 'nothing_silent_wrong_initial_q' initial_q\\(\\) returned"
                            " float32\\[109, 7\\]: must be the task's \\[108, 7\\]")


explorer("nothing_silent_no_probabilities")(_Greedy)


def test_an_explorer_without_probabilities_names_the_learner_that_reads_them():
    refused_before_training(Setting("expected_sarsa", "nothing_silent_no_probabilities"),
                            "does not define probabilities\\(\\) \\(learner 'expected_sarsa'"
                            " reads them")


def test_gymnasium_and_array_inputs_are_one_line_or_plain_numbers(tmp_path):
    from vdbejax.envs.gymnasium_adapter import from_gymnasium
    from vdbejax.results.grid_result import GridResult

    with pytest.raises(ValueError, match="env=42 is invalid: must be a gymnasium environment"):
        from_gymnasium(42)  # was AttributeError: 'int' object has no attribute 'unwrapped'
    # A 0-d numpy or JAX array is a number (was: "ArrayImpl is not JSON serializable").
    assert Setting("qlearning", "egreedy", jnp.asarray(0.5)).param == 0.5
    assert Setting("qlearning", "egreedy", np.array(0.1)) == Setting("qlearning", "egreedy", 0.1)
    result = run_grid(make_mdp(), [Setting("qlearning", "egreedy", jnp.asarray(0.5))],
                      num_seeds=1, num_episodes=2)
    (tmp_path / "file").touch()  # a parent that is a file: was FileNotFoundError
    with pytest.raises(ValueError, match="out_dir=.* is invalid: must be a writable folder"):
        result.save(tmp_path / "file" / "below")
    assert not list(tmp_path.glob("file*/**"))


@explorer("nothing_silent_callback")
class _Callback(Explorer):  # a host function at every step of every agent
    def select(self, q, tables, context, uniforms):
        import jax

        host = jax.pure_callback(lambda v: np.asarray(v), jax.ShapeDtypeStruct((), jnp.float32),
                                 q[0], vmap_method="sequential")
        return jnp.argmax(q + 0.0 * host)


def test_a_plug_in_calling_back_into_python_is_refused_before_training():
    with pytest.raises(ValueError, match="select\\(\\) calls back into Python"):
        run_grid(make_mdp(), [Setting("qlearning", "nothing_silent_callback")], num_seeds=2,
                 num_episodes=2)


def _help_defaults(command: str) -> list[tuple[str, str, object, str]]:
    """``(dest, the default the help prints, the parser's default, help)`` of a command's
    options whose help says ``(default V…``."""
    import argparse
    import re

    parser = cli.build_parser()
    sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
    rows = []
    for action in sub.choices[command]._actions:
        found = re.search(r"\(default (?!:)([^\s;:)]+)", action.help or "")
        if found:
            rows.append((action.dest, found.group(1).rstrip(","), action.default,
                         action.help))
    return rows


def _number(text: str) -> float | None:
    try:
        return float(text)
    except ValueError:
        return None


@pytest.mark.parametrize("command", ["run", "scale"])
def test_every_default_the_help_prints_is_the_one_used(command):
    import inspect

    from vdbejax.cli.study_commands import SCALE_SIZE_FLAGS
    from vdbejax.envs.suite import task_info
    from vdbejax.studies.scaling import run_scaling
    from vdbejax.studies.sweeps import run_sweep
    from vdbejax.studies.task_names import make_task

    function = {"run": run_sweep, "scale": run_scaling}[command]
    used = {name: p.default for name, p in inspect.signature(function).parameters.items()}
    # What a None default means: scale's variants' own horizon.
    own = {"scale": {"max_steps": int(make_task("variant:2x1").max_steps)}, "run": {}}[command]
    if command == "scale":
        used.update({k: v for k, v in SCALE_SIZE_FLAGS.items() if v is not None})
    rows = _help_defaults(command)
    assert {"seeds", "episodes", "seed"} <= {dest for dest, *_ in rows}
    for dest, printed, parser_default, text in rows:
        value = parser_default if parser_default is not None else used.get(dest)
        if value is None:
            value = own.get(dest)
        if _number(printed) is not None:
            assert value is not None and float(value) == _number(printed), (dest, text)
        elif isinstance(value, str):
            assert printed == value, (dest, text)
    if command == "run":  # the task's own horizon, whatever it is
        text = next(a.help for a in cli.build_parser()._actions[-1].choices["run"]._actions
                    if a.dest == "max_steps")
        assert "the task's own horizon" in text and "100 for table_cleaning" in text
        assert int(make_task("table_cleaning").max_steps) == 100
        assert used["max_steps"] is None
        assert int(make_task("riverswim").max_steps) == task_info("riverswim").horizon != 100
