"""Independent random streams derived from one seed, one per purpose.

``stream(seed, "radio")`` is ``default_rng(SeedSequence(seed, spawn_key=(1,)))``: the
building, the radio environment, the magnetic field, the survey and each walker draw from
their own stream, so changing how many numbers one of them draws leaves the others alone.
"""

from __future__ import annotations

from typing import Literal

import numpy as np

Purpose = Literal["building", "radio", "magnetic", "survey", "walker"]

_KEYS: dict[Purpose, int] = {"building": 0, "radio": 1, "magnetic": 2, "survey": 3, "walker": 4}


def sequence(seed: int, purpose: Purpose, *index: int) -> np.random.SeedSequence:
    """The seed sequence for ``purpose`` (and e.g. a walker's number) under ``seed``."""
    return np.random.SeedSequence(seed, spawn_key=(_KEYS[purpose], *index))


def stream(seed: int, purpose: Purpose, *index: int) -> np.random.Generator:
    """The generator for ``purpose`` (and e.g. a walker's number) under ``seed``."""
    return np.random.default_rng(sequence(seed, purpose, *index))


def child(seq: np.random.SeedSequence, *index: int) -> np.random.Generator:
    """A generator for a part of what ``seq`` seeds, without mutating ``seq`` (unlike
    ``SeedSequence.spawn``)."""
    return np.random.default_rng(
        np.random.SeedSequence(seq.entropy, spawn_key=(*seq.spawn_key, *index))
    )
