"""Seeded Gaussian noise streams, one per noise source, drawn in blocks."""
from __future__ import annotations

import numpy as np


class NormalStream:
    """Standard normal draws from its own PCG64 stream, taken in blocks (no per-draw overhead).

    numpy fills a block with the same sequence that single draws would give, so the block size
    does not change any result.
    """

    def __init__(self, seed_sequence: np.random.SeedSequence, block: int = 4096):
        self._rng = np.random.Generator(np.random.PCG64(seed_sequence))
        self._block = block
        self._buf: list[float] = []
        self._i = 0

    def __call__(self) -> float:
        if self._i >= len(self._buf):
            self._buf = self._rng.standard_normal(self._block).tolist()
            self._i = 0
        x = self._buf[self._i]
        self._i += 1
        return x


def noise_streams(seed: int, names: tuple[str, ...]) -> dict[str, NormalStream]:
    """Independent streams for ``names`` from one integer seed; same seed, same draws."""
    children = np.random.SeedSequence(int(seed)).spawn(len(names))
    return {name: NormalStream(child) for name, child in zip(names, children)}
