"""What one upload adds to the maps, from a recorded ILC walk (no servers needed)."""

from __future__ import annotations

import lzma

from server.services.uploads import contribution
from server.storage.models import Upload
from tests.datasets.conftest import dataset_dir


def _upload(level: int = 3) -> Upload:
    path = sorted((dataset_dir("ilc20-sample") / "site2" / "F4" / "path_data_files").iterdir())[0]
    text = lzma.decompress(path.read_bytes())
    return Upload(id="u", site_id="s", content_type="text/plain", payload=text, floor_level=level)


def test_a_walk_is_placed_by_its_steps_and_inertial_selection_thins_it() -> None:
    everything = contribution(_upload())
    assert everything.rejected is None
    assert everything.report["placement"] == "steps between anchors"
    assert 0.5 < everything.report["step_scale"] < 1.6
    steady = contribution(_upload(), inertial_selection=True)
    assert steady.rejected is None
    kept = steady.report["inertial_selection_kept"]
    assert 0.0 < kept < 1.0
    # fewer samples, each of them one the full run placed at the same spot
    assert steady.report["scans"] < everything.report["scans"]
    assert steady.report["magnetic_samples"] < everything.report["magnetic_samples"]
    by_time = {p.t_ms: (p.x_m, p.y_m) for p in everything.points}
    assert all(by_time[p.t_ms] == (p.x_m, p.y_m) for p in steady.points)
    assert any(r.startswith("inertial selection") for r in steady.report["not_used"])
