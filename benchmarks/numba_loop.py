"""Numba per-agent loop: the compiled version of the straightforward implementation.

An independent implementation of `docs/task.md` for speed comparison and
as a statistical cross-check of the engine. It uses its own transition table (built from
:func:`benchmarks.python_loop.env_step`, not from :mod:`vdbejax`), its own random numbers
(splitmix64 per agent, seeded by the agent's seed) and runs the agents one after another
in a single ``@njit(cache=True)`` function (single-threaded, like the Python peer).

numba is a dependency of the ``benchmarks`` extra only; :mod:`vdbejax` never imports it.
"""
from __future__ import annotations

import itertools
import math

import numpy as np
from numba import njit

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
        rng[0] = np.uint64(seeds[i]) * np.uint64(0xD1B54A32D192ED03) + np.uint64(1)
        q[:, :] = q_init
        eps[:] = 1.0
        exp_kind = explorer[i]
        prm = param[i]
        sigma = prm if exp_kind >= 2 else 1.0
        is_sarsa = sarsa[i]
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
            returns[i, e] = total
            lengths[i, e] = t
    return returns, lengths


def run_grid(settings, seeds, episodes, *, alpha=0.8, gamma=0.9, max_steps=100, delta=0.1,
             q_init=0.0, tie_break="random", invalid_action="noop"):
    """Run ``settings × seeds`` agents (config-major order); returns (returns, lengths)."""
    next_state, reward, terminal, starts = build_tables(invalid_action)
    sarsa = np.array([s.learner == "sarsa" for s in settings for _ in seeds], np.bool_)
    explorer = np.array([EXPLORER_CODES[s.explorer] for s in settings for _ in seeds], np.int64)
    param = np.array([s.param for s in settings for _ in seeds], np.float64)
    seed_arr = np.array([seed for _ in settings for seed in seeds], np.int64)
    return train_agents(next_state, reward, terminal, starts, sarsa, explorer, param, seed_arr,
                        episodes, alpha, gamma, max_steps, delta, q_init, tie_break == "first")
