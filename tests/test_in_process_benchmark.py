"""benchmarks.in_process (run_grid of the paper grid called again in one process) and
benchmarks.par (its warm calls beside the harness's numba-2t worker, one sitting)."""
import json
import subprocess
import sys
from pathlib import Path

import pytest

from benchmarks import in_process, par

ROOT = Path(__file__).resolve().parent.parent


def test_each_call_prints_its_wall_and_programs_time(capsys):
    assert in_process.main(["--calls", "2", "--seeds", "1", "--episodes", "3"]) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert [line.split(":")[0] for line in lines] == ["call 1", "call 2"]
    assert all("getting the programs" in line for line in lines)


def test_json_gives_each_calls_wall_and_programs(capsys):
    assert in_process.main(["--calls", "2", "--seeds", "1", "--episodes", "3",
                            "--threads", "1", "--json"]) == 0
    calls = json.loads(capsys.readouterr().out)["calls"]
    assert len(calls) == 2
    assert all(0 < call["programs"] < call["wall"] for call in calls)


def test_par_table_gives_medians_and_numba_over_vdbejax():
    rounds = {"numba-2t": [1.0, 1.5, 1.2],
              "tip:harness": [2.0, 3.0, 2.5], "tip:in-process": [1.6, 1.5, 1.4, 2.0],
              "tip:programs": [0.3, 0.2, 0.4, 0.3], "tip:running": [1.3, 1.3, 1.0, 1.7]}
    table = par.report(rounds).splitlines()
    assert table[0] == "| vdbejax | tip |"
    assert table[2] == "| harness warm worker (fresh process) | 2.50 s (0.48×) |"
    assert table[3] == "| run_grid again in one process (calls 2 on) | 1.55 s (0.77×) |"
    assert table[4] == "| … of which getting the programs | 0.30 s |"
    assert table[5] == "| … the rest (running) | 1.30 s (0.92×) |"
    assert table[6] == "| numba-2t (harness worker) | 1.20 s |"


def test_par_table_has_a_column_per_tree():
    rounds = {"numba-2t": [1.2]}
    for tree, scale in (("baseline", 2.0), ("tip", 1.0)):
        for metric, value in (("harness", 2.4), ("in-process", 1.2), ("programs", 0.3),
                              ("running", 0.9)):
            rounds[f"{tree}:{metric}"] = [value * scale]
    table = par.report(rounds).splitlines()
    assert table[0] == "| vdbejax | baseline | tip |"
    assert table[3] == ("| run_grid again in one process (calls 2 on) | 2.40 s (0.50×) "
                        "| 1.20 s (1.00×) |")
    assert table[6] == "| numba-2t (harness worker) | 1.20 s | |"


@pytest.mark.parametrize("flag, value", [("--calls", "1"), ("--rounds", "0"),
                                         ("--threads", "0"), ("--baseline", "/nonexistent")])
def test_par_bad_arguments_are_one_line_errors_before_any_run(flag, value):
    done = subprocess.run([sys.executable, "-m", "benchmarks.par", flag, value], cwd=ROOT,
                          capture_output=True, text=True, timeout=60)
    assert done.returncode == 2
    assert f"{flag}=" in done.stderr and "is invalid" in done.stderr
    assert "Traceback" not in done.stderr and "round" not in done.stdout


@pytest.mark.benchmark  # fresh processes of vdbejax and numba: left out by .ci/run
def test_par_end_to_end_prints_every_round_and_the_table(tmp_path):
    pytest.importorskip("numba")
    out = tmp_path / "par.json"
    done = subprocess.run([sys.executable, "-m", "benchmarks.par", "--rounds", "1",
                           "--calls", "2", "--seeds", "1", "--episodes", "5",
                           "--baseline", str(ROOT), "--json-out", str(out)], cwd=ROOT,
                          check=True, capture_output=True, text=True)
    assert "round 1: baseline: harness " in done.stdout and "; tip: harness " in done.stdout
    assert "| vdbejax | baseline | tip |" in done.stdout
    rounds = json.loads(out.read_text())
    assert len(rounds["numba-2t"]) == 1
    for tree in ("baseline", "tip"):
        assert [len(rounds[f"{tree}:{m}"]) for m in par.METRICS] == [1, 1, 1, 1]
