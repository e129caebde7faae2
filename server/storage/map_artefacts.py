"""What the worker builds of a radio map version beside the map, as SQL stores it.

The fix-error table goes into a JSON column (``fix_error_to_json``); the FAI maps and the
floor graphs into one compressed array container (``encode_artefacts``, the codec of
``storage.codec``): FAI emitter fits by emitter key and the reference points' DSF in the
version's place order; per floor id its graph's arrays (``graph/<floor id>/<name>``) and
the digest of the plan it was built on, so a process can tell a graph built on an older
plan; the map of reference scans (``scans/<name>``) with each scan's floor by floor id,
so that it reads right whatever floors the site gains later.
"""

from __future__ import annotations

import hashlib
import json
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace
from types import MappingProxyType
from typing import Any

import numpy as np

from server.positioning.plan.navigation_graph import FloorGraph
from server.positioning.radio.accuracy_indicators import FaiMaps
from server.positioning.radio.fix_error import FixErrorModel
from server.positioning.radio.scan_matching import ScanMap
from server.storage.codec import array_to_str, compress_arrays, decompress_arrays, str_to_array

_GRAPH_ARRAYS = ("xy", "kind", "indptr", "indices", "move_p", "stay_p")
_SCAN_ARRAYS = ("xy_m", "indptr", "rows", "rssi_dbm", "fresh", "rarity", "totals")


def plan_digest(geojson: Any) -> str:
    """A short digest of a floor plan, or of several ("" for none): a graph built on
    another plan is not used, a map set cached on other plans is loaded again."""
    if not geojson:
        return ""
    text = json.dumps(geojson, sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def fix_error_to_json(model: FixErrorModel) -> dict[str, Any]:
    return {
        "edges": list(model.edges),
        "sigma_m": {k: list(v) for k, v in model.sigma_m.items()},
        "counts": {k: list(v) for k, v in model.counts.items()},
        "error_68_m": model.error_68_m,
    }


def fix_error_from_json(data: Mapping[str, Any]) -> FixErrorModel:
    return FixErrorModel(
        tuple(int(e) for e in data["edges"]),
        MappingProxyType({k: tuple(float(x) for x in v) for k, v in data["sigma_m"].items()}),
        MappingProxyType({k: tuple(int(x) for x in v) for k, v in data["counts"].items()}),
        float(data["error_68_m"]),
    )


@dataclass(frozen=True)
class Artefacts:
    """A version's FAI maps (emitter fits by key, DSF per reference point in the version's
    place order; None: not built) and its floor graphs by floor id, each with the digest
    of the plan it was built on ("" for a graph over the reference points)."""

    fai_keys: tuple[str, ...]
    fai: FaiMaps | None
    graphs: Mapping[str, tuple[FloorGraph, str]]
    scans: ScanMap | None = None  # floors by index into ``scan_floor_ids``
    scan_floor_ids: tuple[str, ...] = ()

    def scans_on(self, floor_index: Mapping[str, int]) -> ScanMap | None:
        """The reference scans with their floors as indices of the site's floors now;
        None when not built or when a floor they were taken on is gone."""
        if self.scans is None or not all(f in floor_index for f in self.scan_floor_ids):
            return None
        now = np.array([floor_index[f] for f in self.scan_floor_ids], dtype=np.int64)
        return replace(self.scans, floor=now[self.scans.floor] if now.size else self.scans.floor)


def encode_artefacts(
    emitters: Sequence[str],
    fai: FaiMaps | None,
    graphs: Mapping[str, tuple[FloorGraph, str]],
    scans: ScanMap | None = None,
    floor_ids: Sequence[str] = (),
) -> bytes:
    """``emitters`` are the column keys the FAI arrays follow; ``floor_ids`` the floor of
    each floor index of ``scans``."""
    arrays: dict[str, np.ndarray] = {}
    if scans is not None:
        for name in _SCAN_ARRAYS:
            arrays["scans/" + name] = np.ascontiguousarray(getattr(scans, name))
        used = np.unique(scans.floor)
        arrays["scans/floor"] = np.searchsorted(used, scans.floor).astype(np.int32)
        arrays["scans/floor_ids"] = str_to_array("\n".join(floor_ids[i] for i in used.tolist()))
        arrays["scans/emitters"] = str_to_array("\n".join(scans.emitters))
        arrays["scans/decay_per_s"] = np.array([scans.decay_per_s])
    if fai is not None:
        arrays["fai/emitters"] = str_to_array("\n".join(emitters))
        arrays["fai/emitter_xy"] = np.asarray(fai.emitter_xy, dtype=np.float64)
        arrays["fai/p0_dbm"] = np.asarray(fai.p0_dbm, dtype=np.float64)
        arrays["fai/exponent"] = np.asarray(fai.exponent, dtype=np.float64)
        arrays["fai/dsf_m"] = np.asarray(fai.dsf_m, dtype=np.float64)
    for floor_id, (graph, plan_digest) in graphs.items():
        prefix = f"graph/{floor_id}/"
        for name in _GRAPH_ARRAYS:
            arrays[prefix + name] = np.ascontiguousarray(getattr(graph, name))
        arrays[prefix + "spacing_m"] = np.array([graph.spacing_m])
        arrays[prefix + "plan"] = str_to_array(plan_digest)
    return compress_arrays(arrays)


def decode_artefacts(blob: bytes) -> Artefacts:
    arrays = decompress_arrays(blob)
    keys: tuple[str, ...] = ()
    fai = None
    if "fai/emitters" in arrays:
        text = array_to_str(arrays["fai/emitters"])
        keys = tuple(text.split("\n")) if text else ()
        fai = FaiMaps(
            arrays["fai/emitter_xy"].reshape(-1, 2),
            arrays["fai/p0_dbm"],
            arrays["fai/exponent"],
            arrays["fai/dsf_m"],
        )
    graphs: dict[str, tuple[FloorGraph, str]] = {}
    floor_ids = {name.split("/")[1] for name in arrays if name.startswith("graph/")}
    for floor_id in sorted(floor_ids):
        prefix = f"graph/{floor_id}/"
        graph = FloorGraph(
            spacing_m=float(arrays[prefix + "spacing_m"][0]),
            rp_vertex=np.zeros(0, dtype=np.int64),
            **{name: arrays[prefix + name] for name in _GRAPH_ARRAYS},
        )
        graphs[floor_id] = (graph, array_to_str(arrays[prefix + "plan"]))
    if "scans/emitters" not in arrays:
        return Artefacts(keys, fai, graphs)
    names = array_to_str(arrays["scans/emitters"])
    floor_names = array_to_str(arrays["scans/floor_ids"])
    scans = ScanMap(
        floor=arrays["scans/floor"].astype(np.int64),
        emitters=tuple(names.split("\n")) if names else (),
        decay_per_s=float(arrays["scans/decay_per_s"][0]),
        **{name: arrays["scans/" + name] for name in _SCAN_ARRAYS},
    )
    scan_floors = tuple(floor_names.split("\n")) if floor_names else ()
    return Artefacts(keys, fai, graphs, scans, scan_floors)
