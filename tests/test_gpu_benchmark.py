"""benchmarks.gpu runs anywhere (tested on the CPU backend) and maintains its section."""
from __future__ import annotations

from benchmarks import gpu


def test_quick_run_writes_and_replaces_its_section(tmp_path):
    out = tmp_path / "RESULTS.md"
    out.write_text("# Results\n\n## Analysis\n\nhand-written\n")
    assert gpu.main(["--out", str(out), "--quick"]) == 0
    text = out.read_text()
    assert text.startswith("# Results") and "hand-written" in text
    assert text.count(gpu.HEADING) == 1 and "M agent-steps/s" in text
    assert "| 92 | 20 |" in text and "| 368 | 20 |" in text  # 46 × 2 and 46 × 8 agents
    assert "| agents | episodes | cold s | wall s |" in text  # the same call run twice
    gpu.write_section(out, gpu.HEADING + "\n\nnew body\n")
    again = out.read_text()
    assert again.count(gpu.HEADING) == 1 and "new body" in again and "hand-written" in again
    assert "M agent-steps/s" not in again


def test_section_before_another_heading_keeps_what_follows(tmp_path):
    out = tmp_path / "R.md"
    out.write_text(f"intro\n\n{gpu.HEADING}\n\nold\n\n## Later\n\nkept\n")
    gpu.write_section(out, gpu.HEADING + "\n\nfresh\n")
    text = out.read_text()
    assert "old" not in text and "fresh" in text and text.rstrip().endswith("kept")
