"""Studies: commands that train into a result folder, all through one pipeline.

* :mod:`~vdbejax.studies.folder` — :func:`train_in_folder`: check the folder, lock it,
  run (checkpointed, resumable), save, write the outputs. ``vdbejax reproduce``,
  ``vdbejax run``, ``vdbejax scale`` and ``vdbejax ablate`` all train through it;
  :class:`StudyOutputs`: what ``vdbejax scale``, ``bench`` and ``depth`` write besides
  their tables.
"""
from vdbejax.results.io import CHECKPOINT_FILE
from vdbejax.studies.folder import (
    StudyOutputs,
    checkpoint_files,
    train_in_folder,
)

#: The public names; the modules among them are imported when first named
#: (``from vdbejax.studies import sweeps``).
__all__ = [
    "CHECKPOINT_FILE",
    "StudyOutputs",
    "bench",
    "checkpoint_files",
    "depth",
    "learner_defaults",
    "scaling",
    "scaling_adaptive",
    "scaling_report",
    "snapshots",
    "sweep_file",
    "sweeps",
    "task_names",
    "train_in_folder",
]
