"""benchmarks.in_process: run_grid of the paper grid called again in one process."""
from benchmarks import in_process


def test_each_call_prints_its_wall_and_programs_time(capsys):
    assert in_process.main(["--calls", "2", "--seeds", "1", "--episodes", "3"]) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert [line.split(":")[0] for line in lines] == ["call 1", "call 2"]
    assert all("getting the programs" in line for line in lines)
