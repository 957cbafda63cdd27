"""When the inner loop of an outer iteration ends (config field inner_stop).

`STOPPING_RULES` maps each config value to the factory of its part.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Protocol, runtime_checkable

from svrpo.algorithm.lifecycle import Part
from svrpo.config import Config

if TYPE_CHECKING:
    from svrpo.algorithm.gradients import BatchGradients
    from svrpo.algorithm.streams import RandomStreams


@runtime_checkable
class StoppingRule(Protocol):
    """Asked after every inner step that reached the line search; a part with the
    svrpo.algorithm.lifecycle.Part methods (start, state_dict, load_state_dict)."""

    def stop(self, step_accepted: bool) -> bool:
        """True to end the inner loop now (the update then reports stopped_early = 1)."""
        ...

    def start(self, gradients: BatchGradients) -> None: ...

    def state_dict(self) -> dict[str, Any]: ...

    def load_state_dict(self, state: Mapping[str, Any]) -> None: ...


@dataclass(frozen=True)
class RunAllSteps(Part):
    """Always J steps (the authors' code): a rejected step leaves w_j unchanged and goes on."""

    def stop(self, step_accepted: bool) -> bool:
        return False


@dataclass(frozen=True)
class StopAfterFailedSearch(Part):
    """Stop once a line search accepts nothing: the trust region is used up (DESIGN-NOTES note 14)."""

    def stop(self, step_accepted: bool) -> bool:
        return not step_accepted


STOPPING_RULES: dict[str, Callable[[Config, RandomStreams], StoppingRule]] = {
    "all": lambda config, streams: RunAllSteps(),
    "failed_search": lambda config, streams: StopAfterFailedSearch(),
}
"""config.inner_stop value -> (config, the run's random streams) -> the stopping-rule part."""
