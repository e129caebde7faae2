"""The seeded split of an ILC 2.0 site's traces into training and test sets: per floor, by
a shuffle of their path ids.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from lab.datasets.ilc import IlcSite


@dataclass(frozen=True)
class SplitPaths:
    """Trace files per floor index, for training and for testing."""

    train: tuple[tuple[int, Path], ...]
    test: tuple[tuple[int, Path], ...]


def split_site(site: IlcSite, seed: int, train_fraction: float) -> SplitPaths:
    """Seeded split of each floor's traces by path id; at least one on each side when a
    floor has two or more traces."""
    if not 0.0 < train_fraction < 1.0:
        raise ValueError("train_fraction must be between 0 and 1")
    train: list[tuple[int, Path]] = []
    test: list[tuple[int, Path]] = []
    for index, floor in enumerate(site.floors):
        files = sorted(floor.trace_files, key=_path_id)
        rng = np.random.default_rng(np.random.SeedSequence(seed, spawn_key=(index,)))
        order = rng.permutation(len(files))
        n_train = round(train_fraction * len(files))
        if len(files) >= 2:
            n_train = min(max(n_train, 1), len(files) - 1)
        train += [(index, files[i]) for i in sorted(order[:n_train].tolist())]
        test += [(index, files[i]) for i in sorted(order[n_train:].tolist())]
    return SplitPaths(tuple(train), tuple(test))


def restrict(site: IlcSite, paths: Iterable[tuple[int, Path]]) -> IlcSite:
    """The site with only these (floor index, trace file) pairs left."""
    keep = set(paths)
    floors = tuple(
        replace(f, trace_files=tuple(p for p in f.trace_files if (i, p) in keep))
        for i, f in enumerate(site.floors)
    )
    return replace(site, floors=floors)


def _path_id(path: Path) -> str:
    return path.name.split(".", 1)[0]
