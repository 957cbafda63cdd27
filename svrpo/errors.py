"""Errors that stop a training run (shared by the loop and the sampling subsystem)."""


class TrainingError(RuntimeError):
    """The run cannot go on (e.g. sampling workers keep dying); its last iteration is checkpointed."""
