"""Checkpoints of a run: moved to :mod:`vdbejax.runs.checkpoint` (importable from here)."""
from vdbejax.runs.checkpoint import (
    CHECKPOINT_VERSION,
    HINT,
    LOG_SUFFIX,
    CheckpointWriter,
    load_checkpoint,
    log_path,
    remove_checkpoint,
)

__all__ = ["CHECKPOINT_VERSION", "HINT", "LOG_SUFFIX", "CheckpointWriter", "load_checkpoint",
           "log_path", "remove_checkpoint"]
