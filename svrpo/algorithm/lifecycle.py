"""The lifecycle every part of the policy update shares (estimator, direction metric, KL anchor,
stopping rule): built once per run from the config, started at every outer iteration, and
saved and restored with the run's checkpoints.

The update calls these methods on every part alike, so a new part with state (or with
nothing to save) needs no edit in the update, the run or the checkpoint. A part that draws
random numbers takes a named stream from the run's allocator (svrpo/algorithm/streams.py) when it is
built; the allocator saves that stream, so the part's own state_dict stays empty.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from svrpo.algorithm.gradients import BatchGradients


class Part:
    """Defaults for a part that keeps nothing across outer iterations."""

    def start(self, gradients: BatchGradients) -> None:
        """Called at the snapshot w~ of every outer iteration, before the first inner step
        (`gradients` holds the iteration's batch, policy and g~)."""

    def after_step(self, accepted: bool) -> None:
        """Called after every inner step with whether its line search accepted a trial (False
        for a skipped step), for a part whose next step depends on it (the budgeted anchor)."""

    def state_dict(self) -> dict[str, Any]:
        """What must survive a checkpoint between two outer iterations (tensors and plain values)."""
        return {}

    def load_state_dict(self, state: Mapping[str, Any]) -> None:
        """Restore state_dict output; a stateless part refuses a non-empty state (another part's)."""
        if state:
            raise ValueError(f"{type(self).__name__} keeps no state, but the checkpoint holds "
                             f"{', '.join(sorted(state))} for it")
