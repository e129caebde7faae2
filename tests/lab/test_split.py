"""The seeded split of a site's traces into training and test sets."""

from __future__ import annotations

from pathlib import Path

from lab import split
from lab.datasets.ilc import IlcFloor, IlcSite


def _site(n_per_floor: tuple[int, ...]) -> IlcSite:
    floors = tuple(
        IlcFloor(
            name=f"F{i + 1}",
            level=i,
            width_m=10.0,
            height_m=10.0,
            plan=None,
            trace_files=tuple(Path(f"f{i}/p{j:03d}.txt") for j in range(n)),
        )
        for i, n in enumerate(n_per_floor)
    )
    return IlcSite("toy", floors)


def test_split_is_deterministic_disjoint_and_complete() -> None:
    site = _site((10, 5, 2, 1))
    a = split.split_site(site, 7, 0.8)
    b = split.split_site(site, 7, 0.8)
    assert a == b
    train, test = set(a.train), set(a.test)
    assert not train & test
    everything = {(i, p) for i, f in enumerate(site.floors) for p in f.trace_files}
    assert train | test == everything
    per_floor_train = [sum(1 for i, _ in a.train if i == f) for f in range(4)]
    assert per_floor_train == [8, 4, 1, 1]  # 80 %, at least one on each side when possible
    other = split.split_site(site, 8, 0.8)
    assert other.train != a.train


def test_split_ignores_listing_order() -> None:
    site = _site((10,))
    shuffled = IlcSite(
        "toy", (IlcFloor("F1", 0, 10.0, 10.0, None, tuple(reversed(site.floors[0].trace_files))),)
    )
    assert split.split_site(site, 3, 0.8) == split.split_site(shuffled, 3, 0.8)
