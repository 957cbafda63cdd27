"""The run's random streams: one allocator hands every part that draws random numbers a named
torch.Generator, and saves and restores all of them with the run.

A part asks for `streams.generator("its name")` when it is built; the checkpoint then holds
that stream's state without any edit elsewhere, so a new part cannot resume on a fresh stream
by accident. The three streams the learner had before the allocator keep their seeds
(seed + 1, + 2, + 3), so runs made before it reproduce row for row; any other name gets a seed
derived from (seed, name) through NumPy's SeedSequence, independent of the others.
"""

from __future__ import annotations

import zlib
from typing import Any

import numpy as np
import torch

LEGACY_OFFSETS = {"minibatches": 1, "baseline": 2, "probe": 3}
"""Streams that existed before the allocator, at their historical seeds seed + offset."""


def stream_seed(seed: int, name: str) -> int:
    """The seed of stream `name` of a run seeded `seed` (stable across processes and versions)."""
    if name in LEGACY_OFFSETS:
        return seed + LEGACY_OFFSETS[name]
    words = np.random.SeedSequence([seed, zlib.crc32(name.encode())]).generate_state(2, dtype=np.uint32)
    return int(words[0]) << 31 | int(words[1]) >> 1  # 62 bits: a valid torch seed


class RandomStreams:
    """Named torch generators of one run; `state_dict` covers every stream handed out."""

    def __init__(self, seed: int) -> None:
        self.seed = seed
        self._generators: dict[str, torch.Generator] = {}

    def generator(self, name: str) -> torch.Generator:
        """The stream `name` (created on first request; the same object afterwards)."""
        if name not in self._generators:
            generator = torch.Generator()
            generator.manual_seed(stream_seed(self.seed, name))
            self._generators[name] = generator
        return self._generators[name]

    def names(self) -> list[str]:
        return sorted(self._generators)

    def state_dict(self) -> dict[str, Any]:
        return {name: generator.get_state() for name, generator in sorted(self._generators.items())}

    def load_state_dict(self, state: dict[str, Any]) -> None:
        """Restore the streams in `state`; a stream of this run missing from it is an error (the
        checkpoint was written by a run that did not draw from it)."""
        missing = sorted(set(self._generators) - set(state))
        if missing:
            raise KeyError(f"the checkpoint has no state for the random stream(s) {', '.join(missing)}")
        for name, generator_state in state.items():
            self.generator(name).set_state(generator_state)
