"""Errors that stop a run or refuse a file, and their one-line form (torch-free: the CLI names
them without importing torch)."""


class ConfigError(ValueError):
    """A configuration that cannot run, with a message saying which field and why."""


class TrainingError(RuntimeError):
    """The run cannot go on (e.g. sampling workers keep dying); its last iteration is checkpointed."""


class CheckpointError(RuntimeError):
    """A checkpoint that cannot be read or does not fit the run, naming the file."""


class EvaluationError(ValueError):
    """A path that holds no checkpoint, or a video that cannot be rendered."""


class EnvError(ValueError):
    """An environment id that does not exist, or spaces this project cannot handle."""


class SpecError(ValueError):
    """An experiment spec that cannot be run (unknown name, unreadable or invalid YAML)."""


def one_line(error: BaseException) -> str:
    """str(error) with all whitespace runs (newlines included) collapsed: the CLI prints one line."""
    return " ".join(str(error).split())
