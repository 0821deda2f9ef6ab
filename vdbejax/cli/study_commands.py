"""The study commands: ``run`` (any sweep), ``scale``, ``bench`` and ``depth``."""
from __future__ import annotations

import argparse
from pathlib import Path

from vdbejax.cli.common import (
    add_evaluate_flag,
    add_run_flags,
    refuse_sizes_with_quick,
    run_options,
    size_values,
    write_long_csv,
)
from vdbejax.validation import parse_cli_number


def add_run(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "run", help="run any sweep (learners × explorers × hyperparameter axes) and write its"
                    " results, summary and figures",
        description="Flags override the sweep file's keys (vdbejax.studies.sweeps lists them).")
    number = parse_cli_number
    p.add_argument("--out", required=True, help="output folder")
    p.add_argument("--config", default=None,
                   help="sweep file, TOML (.toml) or JSON (docs/sweeps.md), or a finished"
                        " run's folder (trains its sweep again)")
    p.add_argument("--task", default=None,
                   help="a task name: table_cleaning (default), cruz2018 (the authors'"
                        " published table), variant:NxK, riverswim, chain:N, deepsea:N, …"
                        " (vdbejax.envs.suite.NAMES), gym:<id>, module:function or"
                        " file.py:function (returns a TabularMDP)")
    p.add_argument("--learners", default=None, help="comma-separated, e.g. qlearning,sarsa")
    p.add_argument("--explorers", default=None, help="comma-separated, e.g. vdbe,ucb1")
    p.add_argument("--axis", action="append", default=[], metavar="NAME=V1,V2,...",
                   help="a sweep axis, e.g. --axis alpha=0.1,0.3,0.8 (repeatable)")
    p.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                   help="a value shared by every setting that has it, e.g. --set gamma=0.95")
    p.add_argument("--exclude", action="append", default=[], metavar="NAME=V,NAME=V,...",
                   help="leave out the settings of the product that match every NAME=V, e.g."
                        " --exclude learner=sarsa,alpha=0.8 (repeatable)")
    p.add_argument("--setting", action="append", default=[],
                   metavar="learner=L,explorer=E,NAME=V,...",
                   help="an explicit setting, run after the product (repeatable)")
    p.add_argument("--plugin", action="append", default=[], metavar="FILE_OR_MODULE",
                   help="import this file or module first (it registers plug-ins)")
    p.add_argument("--seeds", type=number, default=None, help="agents per setting (default 20)")
    p.add_argument("--replicates", type=number, default=None,
                   help="independent groups of SEEDS agents (default 1; more: summary_pooled.csv"
                        " and replicates.csv beside summary.csv)")
    p.add_argument("--episodes", type=number, default=None,
                   help="episodes per agent (default 1000)")
    p.add_argument("--seed", type=number, default=None, help="root random seed (default 0)")
    p.add_argument("--max-steps", type=number, default=None,
                   help="episode truncation (default: the task's own horizon, the max_steps"
                        " of vdbejax list tasks; 100 for table_cleaning and variant:NxK)")
    p.add_argument("--invalid-action", default=None, help="noop (default) or fail")
    p.add_argument("--chunk-episodes", type=number, default=None,
                   help="episodes per jitted chunk (default: at least 100 and 20,000"
                        " agent-episodes, at most 10,000)")
    add_evaluate_flag(p, "policy_values in returns.npz, the policy_gap and optimal_fraction"
                         " columns of summary.csv, policy_gap.png")
    p.add_argument("--record-optimal", action="store_true", default=None,
                   help="record each episode's fraction of steps whose action is optimal"
                        " (optimal_actions in returns.npz; the optimal_actions and"
                        " reward_per_step columns of summary.csv); the returns are the same")
    p.add_argument("--learner-defaults", default=None, choices=("benchmark", "paper"),
                   help="the values of the settings that give none of their own: benchmark"
                        " (alpha 0.1, gamma 1 - 1/H, the finite-horizon learners gamma 1 and"
                        " horizon H) or paper (alpha 0.8, gamma 0.9) (default: paper on"
                        " table_cleaning, cruz2018 and variant:NxK, benchmark on any other"
                        " task; docs/suite.md)")
    p.add_argument("--instances", default=None, choices=("shared", "per-agent"),
                   help="per-agent: a task family (testbed:N, gaussian_bandit:N,"
                        " bernoulli_bandit:N, garnet:SxAxB, variant:NxK: a random start)"
                        " gives every agent its own instance, drawn from the root seed and"
                        " its seed index (default shared: one task)")
    add_run_flags(p, "continue from OUT/checkpoint.npz (or reuse OUT's whole result)")
    p.add_argument("--no-figures", action="store_true", help="no fig3.png / sensitivity.png")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.add_argument("--long-csv", action="store_true",
                   help="also write returns_long.csv: one row per agent-episode (setting,"
                        " hyperparameters, seed, episode, return, length)")


def _pairs(texts: list[str], flag: str) -> list[tuple[str, str]]:
    pairs = []
    for text in texts:
        name, sep, value = text.partition("=")
        if not sep or not name or not value:
            raise ValueError(f"{flag}={text!r} is invalid: must be NAME=VALUE")
        pairs.append((name, value))
    return pairs


def _value(text: str) -> object:
    if text in ("random", "first"):
        return text
    return parse_cli_number(text)


def _table(text: str, flag: str) -> dict[str, object]:
    """``learner=sarsa,alpha=0.8`` as ``{"learner": "sarsa", "alpha": 0.8}``."""
    pairs = _pairs([part for part in text.split(",") if part], flag)
    if not pairs:
        raise ValueError(f"{flag}={text!r} is invalid: must be NAME=VALUE,NAME=VALUE,...")
    return {name: value if name in ("learner", "explorer") else _value(value)
            for name, value in pairs}


def run_command(args: argparse.Namespace) -> None:
    from vdbejax.studies.sweep_file import SPEC_KEYS, read_sweep_file
    from vdbejax.studies.sweeps import Sweep, run_sweep

    spec = read_sweep_file(args.config) if args.config else {}
    for key in ("task", "seeds", "replicates", "episodes", "seed", "max_steps",
                "invalid_action", "chunk_episodes", "evaluate_every", "record_optimal",
                "instances"):
        if getattr(args, key) is not None:
            spec[key] = getattr(args, key)
    for key in ("learners", "explorers"):
        if getattr(args, key) is not None:
            spec[key] = [name for name in getattr(args, key).split(",") if name]
    if args.learner_defaults is not None:
        spec["learner_defaults"] = args.learner_defaults
    axes = dict(spec.get("axes", {}))
    axes.update({name: [_value(v) for v in values.split(",")]
                 for name, values in _pairs(args.axis, "--axis")})
    shared = dict(spec.get("shared", {}))
    shared.update({name: _value(value) for name, value in _pairs(args.set, "--set")})
    both = sorted(set(axes) & set(shared))
    if both:  # one would override the other without a word
        raise ValueError(f"{both[0]} is both a sweep axis and a shared value (--axis, --set or"
                         " the sweep file's [axes] and [shared]): give it once")
    spec["axes"], spec["shared"] = axes, shared
    spec["plugins"] = list(spec.get("plugins", [])) + args.plugin
    spec["exclude"] = list(spec.get("exclude", [])) + [_table(t, "--exclude")
                                                       for t in args.exclude]
    spec["settings"] = list(spec.get("settings", [])) + [_table(t, "--setting")
                                                         for t in args.setting]
    for key in ("learners", "explorers"):
        if key not in spec and not spec["settings"]:
            raise ValueError(f"{key} is missing: give --{key} or a sweep file with {key} = [...]"
                             " (or explicit settings: --setting, settings = [...])")
    mechanics = {key: spec.pop(key) for key in ("chunk_episodes", "evaluate_every",
                                                "record_optimal") if key in spec}
    sweep = Sweep(**{key: spec.pop(key) for key in SPEC_KEYS if key in spec})
    result = run_sweep(args.out, sweep, figures=not args.no_figures,
                       run=run_options(args, progress=not args.quiet, **mechanics), **spec)
    from vdbejax.results.claim_report import CLAIMS_FILE
    from vdbejax.results.io import read_csv
    from vdbejax.results.summary import SUMMARY_FILE, read_summary

    # summary.csv: one row per setting of this result, written by run_sweep above.
    rows = read_summary(Path(args.out) / SUMMARY_FILE)
    for row, setting in zip(rows, result.settings, strict=True):
        print(f"{setting.label}: final return {row.final_return:.3f}"
              f" [{row.final_ci_low:.3f}, {row.final_ci_high:.3f}]")
    defaults = result.meta.get("learner_defaults", {})
    print(f"learner defaults ({defaults.get('rule')}): alpha={defaults.get('alpha')},"
          f" gamma={defaults.get('gamma')}, finite-horizon learners:"
          f" {defaults.get('finite_horizon')}; a setting's own values above")
    claims_file = Path(args.out) / CLAIMS_FILE
    if claims_file.is_file():  # claims.csv: the claims stated in the sweep, scored
        headlines = {row["claim"]: (row["sentence"], row["headline"])
                     for row in read_csv(claims_file)}
        for number, (sentence, headline) in headlines.items():
            print(f"claim {number}: {headline} — {sentence}")
    print(f"training {result.meta['elapsed_seconds']:.1f} s → {args.out}")
    if args.long_csv:
        print(*write_long_csv(args.out, args.out), sep="\n")


def add_sweep_file(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "sweep-file", help="write the sweep file that trains a finished run again",
        description="From RESULTS/meta.json (a vdbejax run folder): 'vdbejax run --config FILE"
                    " --out NEW' then gives the same results.")
    p.add_argument("--results", required=True, help="a folder written by vdbejax run")
    p.add_argument("--out", default=None, help="the sweep file to write, *.json (default:"
                                               " print it)")


def sweep_file_command(args: argparse.Namespace) -> None:
    import json

    from vdbejax.studies.sweep_file import read_sweep_file, write_sweep_file

    if not Path(args.results).is_dir():
        raise ValueError(f"results={args.results!r} is invalid: must be a result folder")
    spec = read_sweep_file(args.results)
    if args.out is None:
        print(json.dumps(spec, indent=2))
    else:
        print(write_sweep_file(spec, args.out))


def add_scale(sub: argparse._SubParsersAction) -> None:
    # Nothing of vdbejax.studies.scaling here: building the parser (--help, --version) must not
    # import JAX.
    p = sub.add_parser(
        "scale", help="episodes to solve of every exploration method on growing task variants;"
                      " writes scaling.csv, scaling.md, scaling.png",
        description="Each variant trains until every agent has solved it (20-episode moving"
                    " average of the normalised return >= fraction; 0 = the uniformly random"
                    " policy's expected return, 1 = the exact best) or the budget is spent;"
                    " solved agents leave the batch.")
    number = parse_cli_number
    p.add_argument("--out", required=True, help="output folder")
    p.add_argument("--sizes", default=None,
                   help="variants NxK (N sections, K goblets), comma-separated"
                        " (default: the study's, vdbejax.studies.scaling.SIZES)")
    p.add_argument("--seeds", type=number, default=None, help="agents per setting (default 10)")
    p.add_argument("--episodes", type=number, default=None,
                   help="smallest episode budget per agent and variant (default 2000)")
    p.add_argument("--episodes-per-state", type=number, default=None,
                   help="budget per variant: max(EPISODES, this x reachable states)"
                        " (default 3; 0: EPISODES for every variant)")
    p.add_argument("--seconds", type=number, default=None,
                   help="wall-clock budget per variant (default none; machine-dependent)")
    p.add_argument("--seed", type=number, default=0, help="root random seed (default 0)")
    p.add_argument("--learners", default="qlearning,sarsa",
                   help="comma-separated (default qlearning,sarsa)")
    p.add_argument("--methods", default=None,
                   help="comma-separated explorers of vdbejax.studies.scaling.METHODS"
                        " (default all)")
    p.add_argument("--fraction", type=number, default=0.9,
                   help="solved = moving average of the normalised return (0 = random"
                        " policy, 1 = best) >= fraction (default 0.9)")
    p.add_argument("--window", type=number, default=20, help="moving-average window (default 20)")
    p.add_argument("--chunk-episodes", type=number, default=None,
                   help="episodes between stop checks (default max(100, budget/100))")
    p.add_argument("--max-steps", type=number, default=None,
                   help="episode truncation (default 100, the variants' own horizon)")
    p.add_argument("--drop-unsolved", action="store_true",
                   help="skip a setting on larger variants once none of its agents solved one")
    p.add_argument("--quick", action="store_true", help="2x1 and 3x1, 3 seeds, 1000 episodes")
    p.add_argument("--no-figure", action="store_true", help="no scaling.png")
    p.add_argument("--no-runs", action="store_true",
                   help="do not keep the variants' result folders (runs/NxK/)")
    add_run_flags(p, "continue an interrupted study: whole variants are loaded, the"
                      " interrupted one continues from runs/NxK/checkpoint.npz")
    p.add_argument("--quiet", action="store_true", help="no status lines")


#: ``vdbejax scale``'s sizes of the study, which ``--quick`` sets (flag: default).
SCALE_SIZE_FLAGS = {"sizes": None, "seeds": 10, "episodes": 2000, "episodes_per_state": 3.0}


def scale_command(args: argparse.Namespace) -> None:
    from vdbejax.runs import UntilSolved
    from vdbejax.studies.folder import StudyOutputs
    from vdbejax.studies.scaling import QUICK, SIZES, ScalingSize, run_scaling
    from vdbejax.validation import check_positive

    refuse_sizes_with_quick(args.quick, [n for n in SCALE_SIZE_FLAGS
                                         if getattr(args, n) is not None], "study")
    for name, default in SCALE_SIZE_FLAGS.items():
        if getattr(args, name) is None:
            setattr(args, name, ",".join(SIZES) if name == "sizes" else default)

    learners = [n for n in args.learners.split(",") if n]
    methods = None if args.methods is None else args.methods.split(",")
    command = (f"vdbejax scale --out {args.out}" + (" --quick" if args.quick else
               f" --sizes {args.sizes} --seeds {args.seeds} --episodes {args.episodes}"
               f" --episodes-per-state {args.episodes_per_state}")
               + "".join(f" --{flag} {value}" for flag, value in (
                   ("seconds", args.seconds), ("seed", args.seed), ("learners", args.learners),
                   ("methods", args.methods), ("fraction", args.fraction), ("window", args.window),
                   ("chunk-episodes", args.chunk_episodes), ("max-steps", args.max_steps))
                   if value is not None)
               + (" --drop-unsolved" if args.drop_unsolved else ""))
    if args.seconds is not None:  # named as its flag, before the stop is built
        check_positive("seconds", args.seconds)
    size = QUICK if args.quick else ScalingSize(
        sizes=args.sizes, seeds=args.seeds, episodes=args.episodes,
        episodes_per_state=None if args.episodes_per_state == 0 else args.episodes_per_state)
    result = run_scaling(
        args.out, size=size, seed=args.seed, max_steps=args.max_steps,
        solve=UntilSolved(fraction=args.fraction, window=args.window, max_seconds=args.seconds),
        drop_unsolved=args.drop_unsolved, learners=learners, methods=methods,
        outputs=StudyOutputs(figures=not args.no_figure, command=command,
                             save_runs=not args.no_runs),
        run=run_options(args, progress=not args.quiet, chunk_episodes=args.chunk_episodes))
    for row in result.rows:
        print(f"{row['size']} {row['method']}: {row['median_text']}"
              f" ({row['solved']}/{row['agents']} solved)")
    print(f"elapsed: {result.meta['elapsed_seconds']:.1f} s → {args.out}")


def add_bench(sub: argparse._SubParsersAction) -> None:
    # Nothing of vdbejax.studies.bench here: building the parser must not import JAX.
    p = sub.add_parser(
        "bench", help="every exploration method on a suite of tasks, scored by regret against"
                      " the exact optimum; writes bench.md, ranking.csv, aggregate.csv, figures",
        description="Per task: each method's one knob tuned on separate seeds, then the chosen"
                    " candidates run on the reported seeds (docs/BENCHMARK.md).")
    number = parse_cli_number
    p.add_argument("--out", required=True, help="output folder")
    p.add_argument("--group", default="suite", choices=("suite", "bandits"),
                   help="suite (default): the suite's tasks (vdbejax.envs.suite.DEFAULT_SUITE)"
                        " and 20 methods; bandits: three 10-armed bandits and the methods that"
                        " make sense on them, with %% optimal action and reward per step")
    p.add_argument("--tasks", default=None,
                   help="comma-separated task names (default: the group's)")
    p.add_argument("--methods", default=None,
                   help="comma-separated names of vdbejax.studies.bench_methods.METHODS"
                        " (default: the group's)")
    p.add_argument("--seeds", type=number, default=None,
                   help="agents per method and task in the reported run (default 10)")
    p.add_argument("--tune-seeds", type=number, default=None,
                   help="agents per candidate in tuning (default 3)")
    p.add_argument("--episodes", type=number, default=None,
                   help="episodes per agent (default 300)")
    p.add_argument("--seed", type=number, default=0,
                   help="root seed of the reported run; tuning uses seed + 1 (default 0)")
    p.add_argument("--no-tune", action="store_true",
                   help="no tuning: each method at its middle candidate")
    p.add_argument("--cost-limit", type=number, default=None,
                   help="the most products per agent-episode a dense-model method (PSRL:"
                        " S (S + 1) A (H + 1)) may cost on a task, else it is left out of it"
                        " (default: none, every method runs on every task)")
    p.add_argument("--quick", action="store_true",
                   help="3 small tasks, 5 methods, 3 agents, 40 episodes (about a minute)")
    p.add_argument("--no-figures", action="store_true", help="no figures")
    add_evaluate_flag(p, "in the reported runs: the gap to the optimum and the share of optimal"
                         " policies in bench.md and ranking.csv, policy_gap_<task>.png")
    add_run_flags(p, "continue an interrupted benchmark: whole task folders are reused, the"
                     " interrupted one continues from its checkpoint")
    p.add_argument("--quiet", action="store_true", help="no status lines")


def bench_command(args: argparse.Namespace) -> None:
    from vdbejax.studies import bench
    from vdbejax.studies.folder import StudyOutputs

    _, values = size_values(args, ["tasks", "methods", "seeds", "tune_seeds", "episodes"],
                            {"seeds": bench.SEEDS, "tune_seeds": bench.TUNE_SEEDS,
                             "episodes": bench.EPISODES}, "benchmark")
    command = "vdbejax bench --out " + args.out + (
        f" --group {args.group}" if args.group != "suite" else "") + (
        " --quick" if args.quick else "".join(
        f" --{k.replace('_', '-')} {v}" for k, v in values.items() if v is not None)) + (
        f" --seed {args.seed}" + (" --no-tune" if args.no_tune else "")
        + (f" --cost-limit {args.cost_limit}" if args.cost_limit is not None else "")
        + (f" --evaluate-every {args.evaluate_every}" if args.evaluate_every else ""))
    choice = bench.MethodChoice(tune=not args.no_tune, tune_seeds=values.pop("tune_seeds"),
                                **({} if args.cost_limit is None
                                   else {"cost_limit": args.cost_limit}))
    result = bench.run_bench(args.out, seed=args.seed, choice=choice, quick=args.quick,
                             group=args.group, **values,
                             outputs=StudyOutputs(figures=not args.no_figures, command=command),
                             run=run_options(args, progress=not args.quiet,
                                             evaluate_every=args.evaluate_every))
    for row in result.aggregate:
        print(f"{row['title']}: IQM score {row['iqm']:.3f} [{row['iqm_low']:.3f},"
              f" {row['iqm_high']:.3f}], mean rank {row['mean_rank']:.1f}")
    print(f"elapsed: {result.meta['elapsed_seconds']:.1f} s → {Path(args.out) / 'bench.md'}")


def add_depth(sub: argparse._SubParsersAction) -> None:
    # Nothing of vdbejax.studies.depth here: building the parser must not import JAX.
    p = sub.add_parser(
        "depth", help="episodes to solve against the depth N of DeepSea and the chain, per"
                      " method, with growth slopes; writes depth.md, depth.csv, depth.png",
        description="Every benchmark method at its untuned middle candidate, each agent until"
                    " solved or out of budget, on DeepSea and the deterministic chain of"
                    " growing N (docs/BENCHMARK.md, 'Depth scaling').")
    p.add_argument("--out", required=True, help="output folder")
    p.add_argument("--families", default=None, help="deepsea and/or chain (default both)")
    p.add_argument("--sizes", default=None, help="comma-separated depths N (default 4,8,16,32)")
    p.add_argument("--methods", default=None,
                   help="comma-separated names of vdbejax.studies.bench_methods.METHODS"
                        " (default all but PSRL)")
    p.add_argument("--seeds", type=parse_cli_number, default=None,
                   help="agents per method and task (default 10)")
    p.add_argument("--episodes", type=parse_cli_number, default=None,
                   help="episode budget per agent and task (default 1000)")
    p.add_argument("--seed", type=parse_cli_number, default=0, help="root seed (default 0)")
    p.add_argument("--quick", action="store_true",
                   help="N = 4 and 6, 4 methods, 3 agents, 100 episodes (seconds)")
    p.add_argument("--no-figures", action="store_true", help="no figure")
    add_evaluate_flag(p, "a multiple of the study's chunk, max(100, episodes/100): the gap to"
                         " the optimum and the share of optimal policies in depth.md and"
                         " depth.csv")
    add_run_flags(p, "continue an interrupted study: whole task folders are reused, the"
                     " interrupted one continues from its checkpoint")
    p.add_argument("--quiet", action="store_true", help="no status lines")


def depth_command(args: argparse.Namespace) -> None:
    from vdbejax.studies import depth
    from vdbejax.studies.depth_report import interval_text
    from vdbejax.studies.folder import StudyOutputs

    sizes, values = size_values(
        args, ["families", "sizes", "methods", "seeds", "episodes"],
        {"families": ",".join(depth.FAMILIES), "sizes": ",".join(map(str, depth.SIZES)),
         "methods": ",".join(depth.METHODS), "seeds": depth.SEEDS, "episodes": depth.EPISODES},
        "depth study")
    command = "vdbejax depth --out " + args.out + (" --quick" if args.quick else "".join(
        f" --{k} {v}" for k, v in values.items() if sizes[k] is not None)) + (
        f" --seed {args.seed}") + (
        f" --evaluate-every {args.evaluate_every}" if args.evaluate_every else "")
    result = depth.run_depth(args.out, seed=args.seed, quick=args.quick, **values,
                             outputs=StudyOutputs(figures=not args.no_figures, command=command),
                             run=run_options(args, progress=not args.quiet,
                                             evaluate_every=args.evaluate_every))
    for row in result.slopes:
        print(f"{row['family']} {row['title']}: solved up to N = {row['largest_solved']},"
              f" exponent {interval_text(row, 'exponent')}")
    print(f"elapsed: {result.meta['elapsed_seconds']:.1f} s → {Path(args.out) / 'depth.md'}")
