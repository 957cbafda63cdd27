"""When the inner loop of an outer iteration ends before J steps (config field inner_stop)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol, runtime_checkable


@runtime_checkable
class StoppingRule(Protocol):
    """Asked after every inner step that reached the line search."""

    def stop(self, step_accepted: bool) -> bool:
        """True to end the inner loop now (the update then reports stopped_early = 1)."""
        ...


@dataclass(frozen=True)
class RunAllSteps:
    """Always J steps (the authors' code): a rejected step leaves w_j unchanged and goes on."""

    def stop(self, step_accepted: bool) -> bool:
        return False


@dataclass(frozen=True)
class StopAfterFailedSearch:
    """Stop once a line search accepts nothing: the trust region is used up (DESIGN-NOTES note 14)."""

    def stop(self, step_accepted: bool) -> bool:
        return not step_accepted
