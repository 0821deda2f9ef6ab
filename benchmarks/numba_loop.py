"""Numba per-agent loop: the compiled version of the straightforward implementation.

An independent implementation of `docs/task.md` for speed comparison and
as a statistical cross-check of the engine. It uses its own transition table (built from
:func:`benchmarks.python_loop.env_step`, not from :mod:`vdbejax`), its own random numbers
(splitmix64 per agent, seeded by the agent's seed). One ``@njit`` function trains one agent
(:func:`_train_one`); two drivers call it: :func:`run_grid` runs the agents one after another
on one thread (like the Python peer), :func:`run_grid_parallel` spreads them over Numba's
threads with ``prange`` (``parallel=True``). Every agent owns its tables and its random
stream, so both drivers return the same arrays, bit for bit, for any thread count.

numba is a dependency of the ``benchmarks`` extra only; :mod:`vdbejax` never imports it.
"""
from __future__ import annotations

import itertools
import math
import os

import numpy as np
from numba import njit, prange

from benchmarks.python_loop import NUM_ACTIONS, env_step

RADICES = (3, 3, 3, 2, 2)
EXPLORER_CODES = {"egreedy": 0, "softmax": 1, "vdbe": 2, "vdbe_softmax": 3}


def _encode(state) -> int:
    code = 0
    for value, radix in zip(state, RADICES):
        code = code * radix + value
    return code


def build_tables(invalid_action: str = "noop"):
    """Dense ``[108, 7]`` next-state / reward / terminal tables and the 2 start codes."""
    n = int(np.prod(RADICES))
    next_state = np.zeros((n, NUM_ACTIONS), np.int64)
    reward = np.zeros((n, NUM_ACTIONS), np.float64)
    terminal = np.zeros((n, NUM_ACTIONS), np.bool_)
    for state in itertools.product(*(range(r) for r in RADICES)):
        code = _encode(state)
        for a in range(NUM_ACTIONS):
            s2, r, t = env_step(state, a, invalid_action)
            next_state[code, a], reward[code, a], terminal[code, a] = _encode(s2), r, t
    starts = np.array([_encode((0, 2, side, 0, 0)) for side in (0, 1)], np.int64)
    return next_state, reward, terminal, starts


@njit(cache=True, inline="always")
def _next(rng):
    """splitmix64 step on a 1-element uint64 state; returns a uniform in [0, 1)."""
    rng[0] += np.uint64(0x9E3779B97F4A7C15)
    z = rng[0]
    z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
    z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    z = z ^ (z >> np.uint64(31))
    return (z >> np.uint64(11)) * (1.0 / 9007199254740992.0)


@njit(cache=True, inline="always")
def _choose(rng, q, s, explorer, param, eps_s, tie_first, w):
    if explorer == 0:
        p, tau = param, -1.0
    elif explorer == 1:
        p, tau = 1.0, param
    elif explorer == 2:
        p, tau = eps_s, -1.0
    else:
        p, tau = eps_s, 0.001
    m = q[s, 0]
    for a in range(1, NUM_ACTIONS):
        if q[s, a] > m:
            m = q[s, a]
    if _next(rng) < p:
        if tau < 0.0:
            return min(int(_next(rng) * NUM_ACTIONS), NUM_ACTIONS - 1)
        total = 0.0
        for a in range(NUM_ACTIONS):
            w[a] = math.exp((q[s, a] - m) / tau)
            total += w[a]
        x = _next(rng) * total
        last = 0
        for a in range(NUM_ACTIONS):
            if w[a] > 0.0:
                last = a
            x -= w[a]
            if x < 0.0:
                return a
        return last
    count = 0
    for a in range(NUM_ACTIONS):
        if q[s, a] == m:
            if tie_first:
                return a
            count += 1
    k = min(int(_next(rng) * count), count - 1)
    for a in range(NUM_ACTIONS):
        if q[s, a] == m:
            if k == 0:
                return a
            k -= 1
    return 0


@njit(cache=True)
def _train_one(next_state, reward, terminal, starts, is_sarsa, exp_kind, prm, seed, episodes,
               alpha, gamma, max_steps, delta, q_init, tie_first, q, eps, w, rng, returns,
               lengths):
    """One agent's whole training run (the step logic of both drivers).

    Writes the agent's episode returns and lengths into the rows ``returns`` / ``lengths``;
    ``q``, ``eps``, ``w`` and ``rng`` are scratch buffers owned by the caller (reset here).
    The agent's random stream depends on ``seed`` alone.
    """
    rng[0] = np.uint64(seed) * np.uint64(0xD1B54A32D192ED03) + np.uint64(1)
    q[:, :] = q_init
    eps[:] = 1.0
    sigma = prm if exp_kind >= 2 else 1.0
    for e in range(episodes):
        s = starts[min(int(_next(rng) * 2), 1)]
        a = _choose(rng, q, s, exp_kind, prm, eps[s], tie_first, w)
        total = 0.0
        t = 0
        while True:
            s2 = next_state[s, a]
            r = reward[s, a]
            term = terminal[s, a]
            t += 1
            total += r
            a2 = 0
            if is_sarsa:
                a2 = _choose(rng, q, s2, exp_kind, prm, eps[s2], tie_first, w)
                target = r if term else r + gamma * q[s2, a2]
            else:
                m = q[s2, 0]
                for b in range(1, NUM_ACTIONS):
                    if q[s2, b] > m:
                        m = q[s2, b]
                target = r if term else r + gamma * m
            dq = alpha * (target - q[s, a])
            q[s, a] += dq
            x = math.exp(-abs(dq) / sigma)
            eps[s] = delta * (1.0 - x) / (1.0 + x) + (1.0 - delta) * eps[s]
            if term or t >= max_steps:
                break
            if not is_sarsa:
                a2 = _choose(rng, q, s2, exp_kind, prm, eps[s2], tie_first, w)
            s = s2
            a = a2
        returns[e] = total
        lengths[e] = t


@njit(cache=True)
def train_agents(next_state, reward, terminal, starts, sarsa, explorer, param, seeds,
                 episodes, alpha, gamma, max_steps, delta, q_init, tie_first):
    """Train each agent in turn; returns ``(returns [n, E] float64, lengths [n, E] int32)``."""
    n = seeds.shape[0]
    num_states = next_state.shape[0]
    returns = np.zeros((n, episodes), np.float64)
    lengths = np.zeros((n, episodes), np.int32)
    q = np.empty((num_states, NUM_ACTIONS), np.float64)
    eps = np.empty(num_states, np.float64)
    w = np.empty(NUM_ACTIONS, np.float64)
    rng = np.empty(1, np.uint64)
    for i in range(n):
        _train_one(next_state, reward, terminal, starts, sarsa[i], explorer[i], param[i],
                   seeds[i], episodes, alpha, gamma, max_steps, delta, q_init, tie_first, q, eps,
                   w, rng, returns[i], lengths[i])
    return returns, lengths


@njit(cache=True, parallel=True)
def train_agents_parallel(next_state, reward, terminal, starts, sarsa, explorer, param, seeds,
                          episodes, alpha, gamma, max_steps, delta, q_init, tie_first, order):
    """:func:`train_agents` with the agents spread over Numba's threads (``prange``).

    Each agent has its own scratch tables and its own random stream (seeded by its seed,
    nothing shared between iterations), so the results are those of :func:`train_agents`
    whatever the number of threads or the schedule. ``order`` is the order in which the
    ``prange`` iterations visit the agents (a permutation; it balances the threads).
    """
    n = seeds.shape[0]
    num_states = next_state.shape[0]
    returns = np.zeros((n, episodes), np.float64)
    lengths = np.zeros((n, episodes), np.int32)
    pad = 8  # 64 bytes each side: no two threads' scratch buffers share a cache line
    for k in prange(n):
        i = order[k]
        q = np.empty(num_states * NUM_ACTIONS + 2 * pad, np.float64)[pad:-pad].reshape(
            (num_states, NUM_ACTIONS))
        eps = np.empty(num_states + 2 * pad, np.float64)[pad:-pad]
        w = np.empty(NUM_ACTIONS + 2 * pad, np.float64)[pad:-pad]
        rng = np.empty(1 + 2 * pad, np.uint64)[pad:-pad]
        _train_one(next_state, reward, terminal, starts, sarsa[i], explorer[i], param[i],
                   seeds[i], episodes, alpha, gamma, max_steps, delta, q_init, tie_first, q, eps,
                   w, rng, returns[i], lengths[i])
    return returns, lengths


def _grid_arrays(settings, seeds):
    sarsa = np.array([s.learner == "sarsa" for s in settings for _ in seeds], np.bool_)
    explorer = np.array([EXPLORER_CODES[s.explorer] for s in settings for _ in seeds], np.int64)
    param = np.array([s.param for s in settings for _ in seeds], np.float64)
    seed_arr = np.array([seed for _ in settings for seed in seeds], np.int64)
    return sarsa, explorer, param, seed_arr


def run_grid(settings, seeds, episodes, *, alpha=0.8, gamma=0.9, max_steps=100, delta=0.1,
             q_init=0.0, tie_break="random", invalid_action="noop"):
    """Run ``settings × seeds`` agents (config-major order) on one thread.

    Returns ``(returns, lengths)``.
    """
    next_state, reward, terminal, starts = build_tables(invalid_action)
    sarsa, explorer, param, seed_arr = _grid_arrays(settings, seeds)
    return train_agents(next_state, reward, terminal, starts, sarsa, explorer, param, seed_arr,
                        episodes, alpha, gamma, max_steps, delta, q_init, tie_break == "first")


def interleaved_order(n: int, threads: int) -> np.ndarray:
    """Agents ``t, t + T, t + 2T, …`` next to each other for ``t = 0 … T-1`` (``T`` = threads).

    Numba splits a ``prange`` into one contiguous block per thread; the grid's agents are
    config-major (all Q-learning agents first, the costlier SARSA ones last), so contiguous
    blocks of the plain order would give the threads unequal work. In this order every
    block holds every ``T``-th agent: a mix of all settings.
    """
    return np.argsort(np.arange(n) % max(int(threads), 1), kind="stable").astype(np.int64)


def run_grid_parallel(settings, seeds, episodes, *, threads=None, alpha=0.8, gamma=0.9,
                      max_steps=100, delta=0.1, q_init=0.0, tie_break="random",
                      invalid_action="noop"):
    """:func:`run_grid` with the agents spread over ``threads`` Numba threads (``prange``).

    ``threads`` defaults to the CPUs this process may use; it may not exceed
    ``numba.config.NUMBA_NUM_THREADS`` (set the ``NUMBA_NUM_THREADS`` environment variable
    before importing numba for more). The results are bit-identical to :func:`run_grid`'s
    for every thread count: each agent's random stream depends on its seed alone.
    """
    import numba

    if threads is None:
        threads = _available_cpus()
    threads = int(threads)
    if not 1 <= threads <= numba.config.NUMBA_NUM_THREADS:
        raise ValueError(f"threads={threads}: must be in 1..{numba.config.NUMBA_NUM_THREADS} "
                         "(NUMBA_NUM_THREADS)")
    next_state, reward, terminal, starts = build_tables(invalid_action)
    sarsa, explorer, param, seed_arr = _grid_arrays(settings, seeds)
    order = interleaved_order(len(seed_arr), threads)
    before = numba.get_num_threads()
    numba.set_num_threads(threads)
    try:
        return train_agents_parallel(next_state, reward, terminal, starts, sarsa, explorer,
                                     param, seed_arr, episodes, alpha, gamma, max_steps, delta,
                                     q_init, tie_break == "first", order)
    finally:
        numba.set_num_threads(before)


def _available_cpus() -> int:
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1
