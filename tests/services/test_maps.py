"""A site's reference scans as sessions read them: every building's, or none."""

from __future__ import annotations

import numpy as np

from server.positioning.engines.shared.site_maps import FloorRef
from server.positioning.radio import fix_error
from server.positioning.radio.fingerprints import RadioMap
from server.positioning.radio.scan_matching import build_scan_map
from server.services.maps import _learned
from server.storage.map_artefacts import encode_artefacts, fix_error_to_json
from server.storage.models import RadioMapVersion

REFS = (FloorRef("A", "a0", 0), FloorRef("B", "b0", 0))


def _version(floor_id: str, x0: float) -> tuple[RadioMapVersion, bytes]:
    """A built version of one building: three scans on its floor (index 0 of its own)."""
    scans = build_scan_map(
        np.array([[x0, 0.0], [x0 + 1, 0.0], [x0 + 2, 0.0]]),
        np.zeros(3, dtype=np.int64),
        [[(f"wifi:{floor_id}", -50.0 - i)] for i in range(3)],
    )
    blob = encode_artefacts((), None, {}, scans, (floor_id,))
    return RadioMapVersion(fix_error=fix_error_to_json(fix_error.DEFAULT)), blob


def _radio() -> RadioMap:
    zeros = np.zeros((2, 1), dtype=np.float32)
    return RadioMap(
        np.zeros((2, 2), np.float32), np.array([0, 1], np.int32), zeros, zeros,
        np.ones((2, 1), np.int32), ("wifi:x",),
    )  # fmt: skip


def test_every_buildings_scans_on_the_sites_floor_indices() -> None:
    built = [_version("a0", 0.0), _version("b0", 100.0)]
    learned = _learned(built, _radio(), REFS, [None, None], single=False, complete=True)
    assert learned.scans is not None
    assert len(learned.scans) == 6
    assert learned.scans.floor.tolist() == [0, 0, 0, 1, 1, 1]
    assert learned.scans.emitters == ("wifi:a0", "wifi:b0")


def test_a_building_not_yet_built_leaves_the_site_on_its_cells() -> None:
    # building B's version is pending: matching A's scans alone would leave B's phones
    # without a fix, so the site matches on the cells until B is built
    built = [_version("a0", 0.0)]
    learned = _learned(built, _radio(), REFS, [None, None], single=False, complete=False)
    assert learned.scans is None
    # a scan taken on a floor the site no longer has: the same
    gone = [_version("a0", 0.0), _version("c0", 5.0)]
    assert _learned(gone, _radio(), REFS, [None, None], single=False).scans is None
