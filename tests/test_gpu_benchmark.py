"""benchmarks.gpu runs anywhere (tested on the CPU backend) and maintains its section."""
from __future__ import annotations

import numpy as np

from benchmarks import gpu


def test_quick_run_writes_and_replaces_its_section(tmp_path, monkeypatch):
    from vdbejax.runs import plan

    # The lockstep with kinds mixed in one batch, as on an accelerator: the grid runs
    # kind after kind too.
    monkeypatch.setattr(plan, "auto_strategy", lambda *_, **__: ("lockstep", "accelerator"))
    monkeypatch.setattr(plan, "mixes_kinds", lambda: True)
    out = tmp_path / "RESULTS.md"
    out.write_text("# Results\n\n## Analysis\n\nhand-written\n")
    assert gpu.main(["--out", str(out), "--quick"]) == 0
    text = out.read_text()
    assert "kinds mixed in one batch. Kind after kind (`mix_kinds=False`):" in text
    assert text.startswith("# Results") and "hand-written" in text
    assert text.count(gpu.HEADING) == 1 and "M agent-steps/s" in text
    assert "| 92 | 20 |" in text and "| 368 | 20 |" in text  # 46 × 2 and 46 × 8 agents
    assert "| agents | episodes | cold s | wall s |" in text  # the same call run twice
    # Here the "device" is the CPU itself: every agent bit-identical, every setting agrees.
    assert "Against the CPU backend" in text and "92 of 92 agents bit-identical" in text
    assert "46/46 settings agree early, 46/46 finally" in text
    gpu.write_section(out, gpu.HEADING + "\n\nnew body\n")
    again = out.read_text()
    assert again.count(gpu.HEADING) == 1 and "new body" in again and "hand-written" in again
    assert "M agent-steps/s" not in again


def test_agreement_counts_settings_and_bit_identical_agents():
    rng = np.random.default_rng(1)
    reference = rng.normal(size=(46, 20, 400)).astype(np.float32)
    same = gpu.cpu_agreement(reference.copy(), reference)
    assert same["identical"] == 920 and same["early"] == same["final"] == 46
    shifted = reference.copy()
    shifted[3] += 5.0  # one setting learns another curve: it disagrees, the rest agree
    other = gpu.cpu_agreement(shifted, reference)
    assert other["identical"] == 900 and len(other["disagree"]) == 1
    assert other["early"] == other["final"] == 45


def test_section_before_another_heading_keeps_what_follows(tmp_path):
    out = tmp_path / "R.md"
    out.write_text(f"intro\n\n{gpu.HEADING}\n\nold\n\n## Later\n\nkept\n")
    gpu.write_section(out, gpu.HEADING + "\n\nfresh\n")
    text = out.read_text()
    assert "old" not in text and "fresh" in text and text.rstrip().endswith("kept")
