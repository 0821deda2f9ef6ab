"""Pure-Python per-agent loop: the straightforward implementation a researcher would write.

It is an independent implementation of `docs/task.md` (its own
environment code and its own explorers, Python's `random`), used as a speed peer and as a
statistical cross-check of the engine's learning curves.
"""
from __future__ import annotations

import math
import random

# hand_obj: 0 free 1 sponge 2 goblet; hand_pos: 0 left 1 right 2 home; goblet 0/1/2(in hand)
GET, DROP, GO_LEFT, GO_RIGHT, GO_HOME, CLEAN, ABORT = range(7)
NUM_ACTIONS = 7


def env_step(state, action, invalid_action="noop"):
    """Return (next_state, reward, terminal) for a state tuple."""
    obj, pos, gob, left, right = state
    nobj, npos, ngob, nleft, nright = state
    failure = False
    if action == GET:
        if obj == 0 and pos == 2:
            nobj = 1
        elif obj == 0 and pos != 2 and pos == gob:
            nobj, ngob = 2, 2
    elif action == DROP:
        if obj == 1 and pos == 2:
            nobj = 0
        elif obj == 2 and pos != 2:
            nobj, ngob = 0, pos
    elif action in (GO_LEFT, GO_RIGHT, GO_HOME):
        npos = action - GO_LEFT
    elif action == CLEAN:
        if obj == 2 or (pos != 2 and pos == gob):
            failure = True
        elif obj == 1 and pos != 2:
            if pos == 0:
                nleft = 1
            else:
                nright = 1
    else:
        failure = True
    nxt = (nobj, npos, ngob, nleft, nright)
    if invalid_action == "fail" and nxt == state and action not in (GO_LEFT, GO_RIGHT, GO_HOME):
        failure = True
    if failure:
        return nxt, -1.0, True
    if nobj == 0 and npos == 2 and nleft == 1 and nright == 1:
        return nxt, 1.0, True
    return nxt, -0.01, False


def choose(rng, q, explorer, param, eps_s, tie_break="random"):
    if explorer == "egreedy":
        p, tau = param, None
    elif explorer == "softmax":
        p, tau = 1.0, param
    elif explorer == "vdbe":
        p, tau = eps_s, None
    else:
        p, tau = eps_s, 0.001
    if rng.random() < p:
        if tau is None:
            return rng.randrange(NUM_ACTIONS)
        m = max(q)
        w = [math.exp((v - m) / tau) for v in q]
        x = rng.random() * sum(w)
        for a, wa in enumerate(w):
            x -= wa
            if x < 0:
                return a
        return max(a for a in range(NUM_ACTIONS) if w[a] > 0)
    m = max(q)
    best = [a for a, v in enumerate(q) if v == m]
    return best[0] if tie_break == "first" else rng.choice(best)


def train_agent(learner, explorer, param, seed, episodes, *, alpha=0.8, gamma=0.9,
                max_steps=100, sigma_delta=0.1, q_init=0.0, invalid_action="noop",
                tie_break="random"):
    """Train one agent; return (returns, lengths) lists."""
    rng = random.Random(seed)
    q = {}
    eps = {}
    sigma = param if explorer in ("vdbe", "vdbe_softmax") else 1.0

    def row(s):
        if s not in q:
            q[s] = [q_init] * NUM_ACTIONS
            eps[s] = 1.0
        return q[s]

    returns, lengths = [], []
    for _ in range(episodes):
        s = (0, 2, rng.randrange(2), 0, 0)
        a = choose(rng, row(s), explorer, param, eps[s], tie_break)
        total, t = 0.0, 0
        while True:
            s2, r, term = env_step(s, a, invalid_action)
            t += 1
            total += r
            q2 = row(s2)
            if learner == "sarsa":
                a2 = choose(rng, q2, explorer, param, eps[s2], tie_break)
                target = r if term else r + gamma * q2[a2]
            else:
                target = r if term else r + gamma * max(q2)
            dq = alpha * (target - q[s][a])
            q[s][a] += dq
            x = math.exp(-abs(dq) / sigma)
            eps[s] = sigma_delta * (1 - x) / (1 + x) + (1 - sigma_delta) * eps[s]
            if term or t >= max_steps:
                break
            s = s2
            a = a2 if learner == "sarsa" else choose(rng, q2, explorer, param, eps[s2], tie_break)
        returns.append(total)
        lengths.append(t)
    return returns, lengths
