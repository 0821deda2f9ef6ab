"""Grid runs: many settings × seeds through the engine, with checkpoints and resume.

PureJaxRL-style: the jitted engine advances all agents one chunk of episodes at a time;
this module's Python loop shows progress and, after every chunk, atomically writes a
checkpoint from which ``resume=True`` continues bit-identically.
"""
from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import sys
import time
import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import jax
import numpy as np

from vdbejax import io
from vdbejax.agents import AgentOptions, Setting, make_agent, stack_agents
from vdbejax.engine import (
    AgentState,
    ProgressCallback,
    agent_keys,
    broadcast_agents,
    run_agents,
    text_progress,
)
from vdbejax.envs.tabular import TabularMDP
from vdbejax.validation import check_int


@dataclasses.dataclass
class GridResult:
    """Learning curves of a grid.

    Attributes:
      settings: the configurations, in config-index order.
      returns: float32 ``[configs, seeds, episodes]`` episode returns.
      lengths: int32 ``[configs, seeds, episodes]`` episode lengths.
      nonfinite: bool ``[configs, seeds]``: NaN/inf appeared in that agent's Q or ε.
      meta: run description (seed, options, MDP name, elapsed seconds, …).
    """

    settings: list[Setting]
    returns: np.ndarray
    lengths: np.ndarray
    nonfinite: np.ndarray
    meta: dict[str, Any]

    @property
    def num_seeds(self) -> int:
        return int(self.returns.shape[1])

    @property
    def num_episodes(self) -> int:
        return int(self.returns.shape[2])

    def select(self, learner: str | None = None, explorer: str | None = None) -> list[int]:
        """Config indices matching a learner and/or explorer."""
        return [
            i
            for i, s in enumerate(self.settings)
            if (learner is None or s.learner == learner)
            and (explorer is None or s.explorer == explorer)
        ]

    def save(self, out_dir: str | os.PathLike) -> None:
        """Write ``returns.npz``, ``configs.csv`` and ``meta.json`` into ``out_dir``."""
        out = Path(out_dir)
        io.atomic_savez(
            out / io.RETURNS_FILE,
            returns=self.returns,
            lengths=self.lengths,
            nonfinite=self.nonfinite,
        )
        io.save_settings(out / io.CONFIGS_FILE, self.settings)
        io.save_json(out / io.META_FILE, self.meta)

    @classmethod
    def load(cls, out_dir: str | os.PathLike) -> GridResult:
        """Read a result saved by :meth:`save` (no recomputation).

        Raises:
          ValueError: the folder lacks the result files.
        """
        out = Path(out_dir)
        missing = [f for f in (io.RETURNS_FILE, io.CONFIGS_FILE) if not (out / f).exists()]
        if missing:
            raise ValueError(f"results folder {str(out)!r} lacks {', '.join(missing)}")
        with np.load(out / io.RETURNS_FILE) as data:
            returns, lengths = data["returns"], data["lengths"]
            nonfinite = data["nonfinite"] if "nonfinite" in data else np.zeros(returns.shape[:2], bool)
        meta = io.load_json(out / io.META_FILE) if (out / io.META_FILE).exists() else {}
        return cls(io.load_settings(out / io.CONFIGS_FILE), returns, lengths, nonfinite, meta)


def _fingerprint(description: dict[str, Any]) -> str:
    return hashlib.sha256(json.dumps(description, sort_keys=True).encode()).hexdigest()[:16]


def _save_checkpoint(path: Path, fingerprint: str, done: int, agents: AgentState,
                     returns: np.ndarray, lengths: np.ndarray) -> None:
    leaves = {f"agent_{f.name}": np.asarray(getattr(agents, f.name))
              for f in dataclasses.fields(AgentState)}
    io.atomic_savez(path, fingerprint=np.asarray(fingerprint), episodes_done=np.asarray(done),
                    returns=returns, lengths=lengths, **leaves)


def _load_checkpoint(path: Path, fingerprint: str) -> tuple[int, AgentState, np.ndarray, np.ndarray]:
    with np.load(path) as data:
        found = str(data["fingerprint"])
        if found != fingerprint:
            raise ValueError(
                f"checkpoint {str(path)!r} belongs to a different run (fingerprint {found},"
                f" expected {fingerprint}): use the same settings, seeds and options, or a new --out"
            )
        agents = AgentState(**{f.name: data[f"agent_{f.name}"] for f in dataclasses.fields(AgentState)})
        return int(data["episodes_done"]), agents, data["returns"], data["lengths"]


def run_grid(
    mdp: TabularMDP,
    settings: Sequence[Setting],
    *,
    num_seeds: int = 20,
    num_episodes: int = 1000,
    seed: int = 0,
    options: AgentOptions = AgentOptions(),
    chunk_episodes: int = 100,
    progress: bool | ProgressCallback = False,
    checkpoint: str | os.PathLike | None = None,
    resume: bool = False,
) -> GridResult:
    """Train ``num_seeds`` agents for every setting, all in one vectorized program.

    Agent ``(config c, seed i)`` uses key ``fold_in(PRNGKey(seed), i)``: the same seed
    index shares its random stream across configs (common random numbers), and an agent
    gives bit-identical results whether run alone or inside any grid.

    Args:
      mdp: the task.
      settings: the configurations (e.g. :func:`~vdbejax.agents.paper_settings`).
      num_seeds: agents per setting.
      num_episodes: episodes per agent.
      seed: root seed.
      options: α, γ, q_init, tie-break, δ shared by all agents.
      chunk_episodes: episodes per jitted chunk (progress and checkpoint granularity).
      progress: True for a progress bar on stderr, or a callback.
      checkpoint: file to write after every chunk (atomically).
      resume: continue from ``checkpoint`` if it exists.

    Returns:
      :class:`GridResult`.

    Raises:
      ValueError: invalid settings, counts, or a checkpoint from a different run.
    """
    settings = list(settings)
    check_int("num_seeds", num_seeds, 1)
    check_int("num_episodes", num_episodes, 1)
    check_int("seed", seed, 0)
    check_int("chunk_episodes", chunk_episodes, 1)
    if not settings:
        raise ValueError("settings is empty: need at least one setting")
    params = broadcast_agents(stack_agents([make_agent(s, options) for s in settings]), num_seeds)
    keys = np.tile(agent_keys(seed, num_seeds), (len(settings), 1))
    description = {
        "mdp": mdp.name,
        "mdp_tables": _fingerprint_arrays(mdp),
        "settings": [dataclasses.astuple(s) for s in settings],
        "num_seeds": num_seeds,
        "num_episodes": num_episodes,
        "seed": seed,
        "options": dataclasses.asdict(options),
    }
    fingerprint = _fingerprint(description)
    initial = None
    on_chunk = None
    if checkpoint is not None:
        checkpoint = Path(checkpoint)
        if resume and checkpoint.exists():
            initial = _load_checkpoint(checkpoint, fingerprint)

        def on_chunk(done: int, agents: AgentState, returns: np.ndarray, lengths: np.ndarray) -> None:
            _save_checkpoint(checkpoint, fingerprint, done,
                             jax.tree.map(np.asarray, agents), returns, lengths)

    callback = text_progress() if progress is True else (progress or None)
    started = time.perf_counter()
    run = run_agents(mdp, params, keys, num_episodes, chunk_episodes=chunk_episodes,
                     progress=callback, on_chunk=on_chunk, initial=initial)
    elapsed = time.perf_counter() - started
    shape = (len(settings), num_seeds, num_episodes)
    nonfinite = run.nonfinite.reshape(shape[:2])
    if nonfinite.any():
        bad = sorted({settings[c].label for c, _ in zip(*np.nonzero(nonfinite))})
        warnings.warn("NaN or inf appeared in Q or ε for: " + "; ".join(bad), RuntimeWarning,
                      stacklevel=2)
    meta = dict(description, fingerprint=fingerprint, elapsed_seconds=elapsed,
                resumed_from_episode=initial[0] if initial else 0,
                lockstep_iterations=run.iterations, max_steps=int(mdp.max_steps),
                jax_version=jax.__version__, backend=jax.default_backend())
    meta.pop("mdp_tables")
    return GridResult(settings, run.returns.reshape(shape), run.lengths.reshape(shape),
                      nonfinite, meta)


def _fingerprint_arrays(mdp: TabularMDP) -> str:
    digest = hashlib.sha256()
    for leaf in jax.tree.leaves(mdp):
        digest.update(np.asarray(leaf).tobytes())
    return digest.hexdigest()[:16]


def log(message: str) -> None:
    """Status line on stderr (kept off stdout so results can be piped)."""
    print(message, file=sys.stderr, flush=True)
