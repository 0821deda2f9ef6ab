"""The signal audit: Ctrl-C or SIGTERM sent to ``vdbejax run`` at spread moments of its life.

Each trial starts ``python -m vdbejax run`` in a fresh process, sends the signal after a
delay (the delays spread evenly from 0 to ``--until`` seconds, so they fall in Python's
start-up, the imports, the compilation, the training and the saving), and checks what
the issue "Nothing silent" asks:

* the process ends within ``--grace`` seconds of the signal;
* no abort or segfault (rc −6, −11, 134, 139);
* from the command line's start on, exit 130 (SIGINT) or 143 (SIGTERM) with "interrupted"
  and no traceback; during Python's own start-up, before the console script runs,
  Python's default (a ``KeyboardInterrupt`` traceback, rc 1, or the process ended by the
  signal) with nothing created; during Python's finalisation, once the command has
  finished, the process ended by the signal beside a finished result folder;
* no folder lock left behind.

It prints one line per trial that breaks a rule and a tally of exit codes, and exits 1 if
any broke one::

    python -m benchmarks.signal_audit [--trials 120] [--until 3.0] [--grace 3.0]
"""
from __future__ import annotations

import argparse
import collections
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

#: Exit codes of a stop during Python's start-up (its default handling of the signal).
START_UP_CODES = {1, -signal.SIGINT, -signal.SIGTERM}
#: Exit codes of the command line's own stop.
STOP_CODES = {signal.SIGINT: 130, signal.SIGTERM: 143}


def trial(folder: Path, delay: float, number: signal.Signals, grace: float) -> tuple[int, str]:
    """One run stopped after ``delay`` seconds: ``(rc, what broke a rule, or "")``."""
    out = folder / "out"
    shutil.rmtree(out, ignore_errors=True)
    run = subprocess.Popen(
        [sys.executable, "-m", "vdbejax", "run", "--out", str(out), "--learners", "qlearning",
         "--explorers", "egreedy,vdbe", "--seeds", "4", "--episodes", "3000",
         "--chunk-episodes", "500", "--quiet"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    time.sleep(delay)
    sent = time.monotonic()
    run.send_signal(number)
    try:
        _, err = run.communicate(timeout=grace + 60)
    except subprocess.TimeoutExpired:
        run.kill()
        return -9, "did not end"
    waited = time.monotonic() - sent
    rc = run.returncode
    problems = []
    if waited > grace:
        problems.append(f"ended {waited:.1f} s after the signal")
    if rc == STOP_CODES[number]:
        if "interrupted" not in err or "Traceback" in err:
            problems.append("no one-line 'interrupted'")
    elif rc == 0:
        pass  # the run had finished before the signal came
    elif rc in START_UP_CODES:  # Python's own start-up, or its finalisation after the command
        finished = (out / "manifest.json").exists() and not (out / ".vdbejax-writing").exists()
        if out.exists() and not finished:
            problems.append("Python's default stop, yet a folder was created")
    else:
        problems.append(f"rc {rc}")
    if (out / ".vdbejax.lock").exists():
        problems.append("lock file left")
    return rc, "; ".join(problems) + (f": {err.strip()[-300:]!r}" if problems else "")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--trials", type=int, default=120)
    parser.add_argument("--until", type=float, default=3.0, help="latest delay, seconds")
    parser.add_argument("--grace", type=float, default=3.0,
                        help="longest wait after the signal, seconds")
    args = parser.parse_args(argv)
    tally: collections.Counter[tuple[str, int]] = collections.Counter()
    broken = 0
    with tempfile.TemporaryDirectory() as folder:
        for k in range(args.trials):
            number = (signal.SIGINT, signal.SIGTERM)[k % 2]
            delay = args.until * k / max(args.trials - 1, 1)
            rc, problem = trial(Path(folder), delay, number, args.grace)
            tally[number.name, rc] += 1
            if problem:
                broken += 1
                print(f"{number.name} at {delay:.3f} s: {problem}")
    print(f"{args.trials} trials, {broken} broke a rule; exit codes:",
          ", ".join(f"{name} {rc}: {n}" for (name, rc), n in sorted(tally.items())))
    return 1 if broken else 0


if __name__ == "__main__":
    sys.exit(main())
