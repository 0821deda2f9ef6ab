"""Checkpoints of a run: what :func:`~vdbejax.runs.run_grid` writes after every
chunk so that ``resume=True`` continues bit-identically after any interruption.

A checkpoint is two files:

* ``<name>`` (e.g. ``checkpoint.npz``): the small part, rewritten atomically after every
  chunk — the run's fingerprint, every agent's episode count and NaN flag, and the full
  state (Q, tables, position, random-stream counter) of the agents started but
  unfinished. Its size depends on the batch, not on how long the run is.
* ``<name>.episodes``: an append-only log of episode returns and lengths. Each chunk
  appends only the episodes it ran (one record per group of agents: their rows, the
  episode range, the returns, the lengths, the episodes the step limit cut (a byte
  each), and in a run that records them the counts of optimal actions), so writing a
  checkpoint costs time proportional to the chunk, however many episodes came before.
  The small file records how many bytes of the log it covers: bytes a killed run
  appended after that are ignored (and cut off) on resume.

Both carry checksums: the small file the sha256 of all its arrays (:func:`contents_digest`),
every record of the log the CRC-32 of its bytes. On resume both are checked before anything
trains: the fingerprint, the layout version, the checksums (a flipped bit or an edited value
is refused), array shapes, types and ranges (episode counts, states, actions, the agents'
random keys), that the log covers exactly the episodes each agent has done, and that the
log belongs to the small file (a random id).
"""
from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import os
import secrets
import struct
import zlib
from collections.abc import Iterator
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np

from vdbejax.engine import AgentState
from vdbejax.engine.agent_state import STATE_DTYPES, table_shape
from vdbejax.envs.tabular import TabularMDP
from vdbejax.results import io
from vdbejax.runs.run_state import RunState

#: Version of the checkpoint layout (a checkpoint of another version is refused).
CHECKPOINT_VERSION = 7
LOG_SUFFIX = ".episodes"
_LOG_MAGIC = b"vdbejax-episode-log-7\n"
_HEADER = struct.Struct("<16s16s")  # fingerprint, log id (ASCII)
_RECORD = struct.Struct("<qqq")  # agents in the record, first episode, end episode
_CRC = struct.Struct("<I")  # after each record: CRC-32 of its header and arrays
CHECKSUM_KEY = "checksum"
HINT = "delete it or use a new output folder"


def contents_digest(arrays: dict[str, np.ndarray]) -> str:
    """sha256 of a checkpoint's arrays (every key but :data:`CHECKSUM_KEY`): names, types,
    shapes and bytes, in name order."""
    digest = hashlib.sha256()
    for name in sorted(arrays):
        if name == CHECKSUM_KEY:
            continue
        value = np.ascontiguousarray(arrays[name])
        digest.update(f"{name}|{value.dtype.str}|{value.shape}|".encode())
        if value.size:  # its bytes, without a copy (a view cannot cast an empty array)
            digest.update(value.data.cast("B"))
    return digest.hexdigest()


def log_path(path: str | os.PathLike) -> Path:
    """The episode log beside checkpoint ``path``."""
    path = Path(path)
    return path.with_name(path.name + LOG_SUFFIX)


def remove_checkpoint(path: str | os.PathLike) -> None:
    """Delete a checkpoint (both files), e.g. once the run's results are saved."""
    Path(path).unlink(missing_ok=True)
    log_path(path).unlink(missing_ok=True)


class CheckpointWriter:
    """Writes the checkpoint after every chunk (call it with the sweep's progress).

    Args:
      path: the small file; the log goes beside it (:func:`log_path`).
      fingerprint: the run's fingerprint (16 characters).
      resumed: the progress a resumed run starts from (its episodes are in the log
        already), or ``None`` for a fresh run (the log is started anew).
      log_bytes: for a resumed run, the log length its small file covers.
      log_id: for a resumed run, the log's id.
    """

    def __init__(self, path: Path, fingerprint: str, resumed: RunState | None = None,
                 log_bytes: int = 0, log_id: str | None = None) -> None:
        self.path = Path(path)
        self.fingerprint = fingerprint
        self._log: BinaryIO | None = None
        if resumed is None:  # the log starts with the first checkpoint: a run stopped before
            self.log_id = secrets.token_hex(8)  # it leaves no file
            self.written = None
        else:
            assert log_id is not None  # a resumed run continues its own log
            self.log_id = log_id
            self.written = np.array(resumed.episodes_done, np.int64)
            log = open(log_path(self.path), "r+b")  # noqa: SIM115  (kept open for the run)
            self._log = log
            log.truncate(log_bytes)  # what a killed run appended past its last checkpoint
            log.seek(log_bytes)

    def _open_fresh(self) -> None:
        log = open(log_path(self.path), "wb")  # noqa: SIM115  (kept open for the run)
        self._log = log
        log.write(_LOG_MAGIC + _HEADER.pack(self.fingerprint.encode().ljust(16)[:16],
                                            self.log_id.encode()))

    def __call__(self, sweep: RunState) -> None:
        if self._log is None and self.written is None:  # the first checkpoint of a fresh run
            self._open_fresh()
        log = self._log
        assert log is not None  # open until close()
        done = np.asarray(sweep.episodes_done, np.int64)
        written = np.zeros_like(done) if self.written is None else self.written
        changed = np.flatnonzero(done != written)
        # One record per group of agents that ran the same episodes in this chunk.
        spans = (np.stack([written[changed], done[changed]], axis=1) if changed.size
                 else np.zeros((0, 2), np.int64))
        for start, stop in np.unique(spans, axis=0):
            rows = changed[(spans[:, 0] == start) & (spans[:, 1] == stop)]
            record = b"".join((
                _RECORD.pack(len(rows), int(start), int(stop)), rows.astype("<i8").tobytes(),
                np.ascontiguousarray(sweep.returns[rows, start:stop], "<f4").tobytes(),
                np.ascontiguousarray(sweep.lengths[rows, start:stop], "<i4").tobytes(),
                np.ascontiguousarray(sweep.cut[rows, start:stop], np.uint8).tobytes(),
                b"" if sweep.optimal is None else
                np.ascontiguousarray(sweep.optimal[rows, start:stop], "<i4").tobytes()))
            log.write(record)
            log.write(_CRC.pack(zlib.crc32(record)))
        log.flush()
        os.fsync(log.fileno())  # the log before the small file that vouches for it
        leaves = {}
        if sweep.state is not None:
            leaves = {f"agent_{f.name}": np.asarray(getattr(sweep.state, f.name))
                      for f in dataclasses.fields(AgentState) if f.name != "tables"}
            leaves.update({f"agent_table_{name}": np.asarray(table)
                           for name, table in sweep.state.tables.items()})
        arrays = dict(
            fingerprint=np.asarray(self.fingerprint),
            version=np.asarray(CHECKPOINT_VERSION), log_id=np.asarray(self.log_id),
            log_bytes=np.asarray(log.tell(), np.int64), num_episodes=np.asarray(
                sweep.num_episodes, np.int64),
            episodes_done=done, stopped=np.asarray(sweep.stopped),
            nonfinite=np.asarray(sweep.nonfinite), state_rows=np.asarray(sweep.state_rows),
            **leaves,
        )
        if sweep.policy_values is not None:  # a run that evaluates its greedy policies
            arrays["policy_values"] = np.asarray(sweep.policy_values, np.float32)
        if sweep.optimal is not None:  # the running episodes' counts of optimal actions so far
            rows = np.asarray(sweep.state_rows, np.int64)
            arrays["running_optimal"] = np.asarray(sweep.optimal[rows, done[rows]], np.int32)
        io.atomic_savez(self.path, compressed=False, **arrays,
                        **{CHECKSUM_KEY: np.asarray(contents_digest(arrays))})
        self.written = done.copy()

    def close(self) -> None:
        if self._log is not None:
            self._log.close()
            self._log = None


@contextlib.contextmanager
def writing(writer: CheckpointWriter | None) -> Iterator[None]:
    """Close ``writer`` (if any) when the run ends; a Ctrl-C that ends it names the
    checkpoint that resumes it (Python's ``KeyboardInterrupt`` in a Python session)."""
    try:
        yield
    except KeyboardInterrupt as stop:
        if writer is not None and writer.path.exists():
            stop.add_note(f"vdbejax: the checkpoint {str(writer.path)!r} keeps the episodes run"
                          " so far: the same call with resume=True continues from there")
        raise
    finally:
        if writer is not None:
            writer.close()


def load_checkpoint(path: Path, fingerprint: str, shape: tuple[int, int],
                    mdp: TabularMDP | None = None, layout: dict[str, str] | None = None,
                    keys: np.ndarray | None = None,
                    evaluations: int | None = None,
                    record_optimal: bool = False) -> tuple[RunState, int, str]:
    """Read a checkpoint of this run and check it (module docstring).

    Args:
      path: the small file.
      fingerprint: the run's.
      shape: ``(agents, episodes)`` of the run.
      mdp: the task (checks Q, table, state and action ranges), if known.
      layout: the agents' table layout (:func:`~vdbejax.methods.agents.table_layout`).
      keys: uint32 ``[agents, 2]``: the random keys of the run's agents, in row order.
      evaluations: the policy evaluations the run takes (None: none).
      record_optimal: the run records each episode's count of optimal actions (its log
        holds them).

    Returns:
      ``(progress, log_bytes, log_id)``.

    Raises:
      ValueError: unreadable, of another run or layout, or contents out of shape or range.
    """
    try:
        with np.load(path) as data:
            stored = {key: data[key] for key in data.files}
        version = int(stored["version"]) if "version" in stored else 1
        if version != CHECKPOINT_VERSION:
            raise ValueError(f"checkpoint {str(path)!r} has layout version {version},"
                             f" expected {CHECKPOINT_VERSION}: {HINT}")
        if str(stored.get(CHECKSUM_KEY, "")) != contents_digest(stored):
            raise ValueError(f"checkpoint {str(path)!r} is damaged: its contents do not match"
                             f" its checksum (a changed bit or an edited value); {HINT}")
        found = str(stored["fingerprint"])
        if found != fingerprint:
            raise ValueError(
                f"checkpoint {str(path)!r} belongs to a different run (fingerprint {found},"
                f" expected {fingerprint}): use the same settings, seeds and options, or {HINT}"
            )
        state = None
        if "agent_q" in stored:
            tables = {key.removeprefix("agent_table_"): stored[key] for key in stored
                      if key.startswith("agent_table_")}
            state = AgentState(tables=tables, **{
                f.name: stored[f"agent_{f.name}"] for f in dataclasses.fields(AgentState)
                if f.name != "tables"})
        episodes_done = np.asarray(stored["episodes_done"], np.int64)
        nonfinite, state_rows = stored["nonfinite"], np.asarray(stored["state_rows"])
        stopped = np.asarray(stored["stopped"])
        log_bytes, log_id = int(stored["log_bytes"]), str(stored["log_id"])
        num_episodes = int(stored["num_episodes"])
        policy_values = stored.get("policy_values")
        running_optimal = stored.get("running_optimal")
    except Exception as error:  # a damaged file: zip, pickle, EOF or key errors
        if isinstance(error, ValueError) and str(error).startswith(f"checkpoint {str(path)!r}"):
            raise  # ours: another run's or another layout's checkpoint
        raise ValueError(f"checkpoint {str(path)!r} is unreadable ({type(error).__name__}:"
                         f" {error}): {HINT}") from None
    if (len(episodes_done), num_episodes) != tuple(shape):
        raise ValueError(f"checkpoint {str(path)!r} is of {len(episodes_done)} agents ×"
                         f" {num_episodes} episodes, expected {shape[0]} × {shape[1]}: {HINT}")
    problem = _check_progress(episodes_done, stopped, nonfinite, state_rows, state, shape, mdp,
                              layout, None if keys is None else np.asarray(keys, np.uint32))
    if problem:
        raise ValueError(f"checkpoint {str(path)!r} is damaged: {problem}; {HINT}")
    if (evaluations is None) != (policy_values is None) or (policy_values is not None and (
            policy_values.shape != (shape[0], evaluations) or policy_values.dtype != np.float32)):
        raise ValueError(f"checkpoint {str(path)!r} is damaged: it does not hold the policy"
                         f" evaluations of this run (float32 [{shape[0]}, {evaluations}]); {HINT}")
    returns, lengths, cut, optimal = _read_log(path, fingerprint, log_id, log_bytes,
                                               episodes_done, shape, record_optimal)
    if optimal is not None:  # a checkpoint may fall mid-episode: its count so far
        if (running_optimal is None or running_optimal.shape != state_rows.shape
                or running_optimal.dtype != np.int32 or (running_optimal < 0).any()):
            raise ValueError(f"checkpoint {str(path)!r} is damaged: it does not hold the"
                             f" running episodes' counts of optimal actions (int32"
                             f" [{state_rows.size}], at least 0); {HINT}")
        optimal[state_rows, episodes_done[state_rows]] = running_optimal
    progress = RunState(returns=returns, lengths=lengths, cut=cut, episodes_done=episodes_done,
                        stopped=stopped, nonfinite=nonfinite, state_rows=state_rows,
                        state=state, policy_values=policy_values, optimal=optimal)
    return progress, log_bytes, log_id


def _read_log(path: Path, fingerprint: str, log_id: str, log_bytes: int,
              episodes_done: np.ndarray, shape: tuple[int, int], record_optimal: bool = False
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]:
    """Replay the episode log into ``[agents, episodes]`` returns, lengths and cut flags
    (and, with ``record_optimal``, the counts of optimal actions; else ``None``)."""
    log = log_path(path)

    def damaged(what: str) -> ValueError:
        return ValueError(f"checkpoint log {str(log)!r} is damaged: {what}; {HINT}")

    try:
        with open(log, "rb") as f:
            data = f.read(log_bytes)
    except OSError as error:
        raise ValueError(f"checkpoint log {str(log)!r} is unreadable ({error.strerror or error}):"
                         f" {HINT}") from None
    head = len(_LOG_MAGIC) + _HEADER.size
    if len(data) != log_bytes or data[:len(_LOG_MAGIC)] != _LOG_MAGIC:
        raise damaged(f"it holds {len(data)} of the {log_bytes} bytes its checkpoint covers"
                      if len(data) != log_bytes else "not an episode log")
    found, found_id = (x.decode(errors="replace").strip() for x in
                       _HEADER.unpack_from(data, len(_LOG_MAGIC)))
    if found != fingerprint[:16] or found_id != log_id:
        raise damaged("it belongs to another checkpoint")
    agents, episodes = shape
    returns = np.zeros(shape, np.float32)
    lengths = np.zeros(shape, np.int32)
    cut = np.zeros(shape, bool)
    optimal = np.zeros(shape, np.int32) if record_optimal else None
    arrays = 3 if record_optimal else 2  # 4-byte values per agent-episode in a record
    covered = np.zeros(agents, np.int64)  # episodes written so far, per agent
    offset = head
    while offset < log_bytes:
        if offset + _RECORD.size > log_bytes:
            raise damaged("a record is cut short")
        count, start, stop = _RECORD.unpack_from(data, offset)
        width = stop - start
        size = count * 8 + (arrays * 4 + 1) * count * max(width, 0)  # (+ the cut byte)
        if count < 1 or not 0 <= start < stop <= episodes or (
                offset + _RECORD.size + size + _CRC.size > log_bytes):
            raise damaged(f"a record of {count} agents × episodes [{start}, {stop})"
                          " is out of range")
        end = offset + _RECORD.size + size
        (crc,) = _CRC.unpack_from(data, end)
        if zlib.crc32(data[offset:end]) != crc:
            raise damaged(f"a record (agents × episodes [{start}, {stop})) does not match its"
                          " checksum (a changed bit or an edited value)")
        offset += _RECORD.size
        rows = np.frombuffer(data, "<i8", count, offset)
        offset += count * 8
        if rows.min() < 0 or rows.max() >= agents or (covered[rows] != start).any():
            raise damaged("a record names agents out of range or out of order")
        block = count * width
        returns[rows, start:stop] = np.frombuffer(data, "<f4", block, offset).reshape(count, width)
        offset += block * 4
        lengths[rows, start:stop] = np.frombuffer(data, "<i4", block, offset).reshape(count, width)
        offset += block * 4
        flags = np.frombuffer(data, np.uint8, block, offset).reshape(count, width)
        if flags.max(initial=0) > 1:
            raise damaged("a record's cut flags are not 0 or 1")
        cut[rows, start:stop] = flags.astype(bool)
        offset += block
        if optimal is not None:
            optimal[rows, start:stop] = np.frombuffer(data, "<i4", block, offset).reshape(
                count, width)
            offset += block * 4
        offset += _CRC.size
        covered[rows] = stop
    if not np.array_equal(covered, episodes_done):
        raise damaged("it does not cover exactly the episodes its checkpoint says were done")
    return returns, lengths, cut, optimal


def _check_progress(done: np.ndarray, stopped: np.ndarray, nonfinite: Any, rows: np.ndarray,
                    state: AgentState | None,
                    shape: tuple[int, int], mdp: TabularMDP | None,
                    layout: dict[str, str] | None, keys: np.ndarray | None) -> str | None:
    """What in a checkpoint's arrays cannot come from this run (``None``: nothing)."""
    agents, episodes = shape
    if np.shape(nonfinite) != (agents,):
        return "its nonfinite flags do not match its agents"
    if np.shape(stopped) != (agents,) or stopped.dtype != bool:
        return "its stopped flags do not match its agents"
    if done.size and (done.min() < 0 or done.max() > episodes):
        return f"episodes_done must lie in [0, {episodes}]"
    if rows.ndim != 1 or len(np.unique(rows)) != len(rows) or (
            rows.size and (rows.min() < 0 or rows.max() >= agents
                           or (done[rows] >= episodes).any() or stopped[rows].any())):
        return "state_rows must name distinct unfinished agents"
    if state is None:
        return None if rows.size == 0 else "state_rows name agents but no agent state is stored"
    m = len(rows)
    if any(np.shape(getattr(state, f.name))[:1] != (m,) for f in dataclasses.fields(AgentState)
           if f.name != "tables"):
        return f"every agent-state array must have {m} rows (one per state_rows entry)"
    for name, dtype in STATE_DTYPES.items():
        if np.asarray(getattr(state, name)).dtype != np.dtype(dtype):
            return (f"agent {name} must be {np.dtype(dtype).name}, not"
                    f" {np.asarray(getattr(state, name)).dtype}")
    for name, table in state.tables.items():
        if np.asarray(table).dtype != np.float32:
            return f"table {name!r} must be float32, not {np.asarray(table).dtype}"
    if keys is not None and not np.array_equal(np.asarray(state.key), keys[rows]):
        return "the agents' random keys are not those of this run's agents"
    if not np.array_equal(np.asarray(state.episode), done[rows]):
        return "the agents' episode counters disagree with episodes_done"
    if mdp is None:
        return None
    S, A = mdp.num_states, mdp.num_actions
    if np.shape(state.q) != (m, S, A):
        return f"Q must be [{m}, {S}, {A}], not {list(np.shape(state.q))}"
    if (np.asarray(state.state) < 0).any() or (np.asarray(state.state) >= S).any():
        return f"agent states must lie in [0, {S})"
    if (np.asarray(state.action) < 0).any() or (np.asarray(state.action) >= A).any():
        return f"agent actions must lie in [0, {A})"
    if layout is not None:
        if set(state.tables) != set(layout):
            return f"tables must be {sorted(layout)}, not {sorted(state.tables)}"
        for name, per in layout.items():
            wanted = (m, *table_shape(mdp, per))
            if np.shape(state.tables[name]) != wanted:
                return (f"table {name!r} must be {list(wanted)},"
                        f" not {list(np.shape(state.tables[name]))}")
    return None
