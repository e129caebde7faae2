"""WiFi fingerprint sets of Universitat Jaume I: UJIIndoorLoc and the long-term library set.

Both become ``Fingerprints``: one row per fingerprint, one column per access point, RSS
in dBm with NaN where the access point was not heard (the files write ``+100``).

UJIIndoorLoc (``../shared/data/ujiindoorloc/``, ``trainingData.csv`` 19,937 rows,
``validationData.csv`` 1,111 rows, also ``.csv.xz``): one CSV with a header row,
``WAP001..WAP520`` then ``LONGITUDE, LATITUDE, FLOOR, BUILDINGID, SPACEID,
RELATIVEPOSITION, USERID, PHONEID, TIMESTAMP``. Positions are EPSG:3857 Web-Mercator
metres as given (at 40° N a Web-Mercator metre is about 0.766 ground metres; published
UJIIndoorLoc errors are in Web-Mercator metres too).

UJI long-term WiFi set (``../shared/data/uji-longterm-wifi/db.tar.xz``, or the extracted
``db/`` directory): ``db/MM/`` per collection month ``01..25``, each holding sets
``dddNN`` with ``ddd`` = ``trn`` (training) or ``tst`` (test), ``NN`` = set number, and
per set four header-less CSVs whose row *i* describe fingerprint *i*:

- ``dddNNrss.csv``: 620 RSS columns (access points in a fixed order, named here
  ``AP001..AP620``), ``100`` = not heard;
- ``dddNNcrd.csv``: x, y in metres of the library's local frame, floor number (3 or 5);
- ``dddNNtms.csv``: ``YYYYMMDDhhmmssSSS`` local clock time;
- ``dddNNids.csv``: ``MMSSKPPPRR`` = month, set, kind (1 training, 2 test), point,
  repetition (month has one or two digits).

Month 01 has 15 training and 5 test sets, months 02-24 one training and 5 test sets,
month 25 two training and 10 test sets (training 02 and tests 06-10 of month 25 taken with
a Samsung Galaxy A5 2017, everything else with a Samsung Galaxy S3); 23,040 training and
81,120 test fingerprints in all.

Left as found in the files: the first point of ``01/trn14`` (6 rows) has floor 0 and a
position no other set uses; ``02/tst03`` has a time with second 60 (carried into the next
minute here).
"""

from __future__ import annotations

import io
import lzma
import re
import tarfile
from collections.abc import Iterator
from dataclasses import dataclass, replace
from pathlib import Path
from typing import IO, Literal

import numpy as np
from numpy.typing import NDArray

from server.positioning.model.events import RadioReading

NOT_HEARD_DBM = 100.0  # what both UJI sets write for an access point not heard

PHONE_GALAXY_S3 = 0
PHONE_GALAXY_A5_2017 = 1

_UJIINDOORLOC_COLUMNS = ("LONGITUDE", "LATITUDE", "FLOOR", "BUILDINGID", "PHONEID", "TIMESTAMP")
_LONGTERM_N_AP = 620
_LONGTERM_FILE = re.compile(r"(?:^|/)(\d\d)/(trn|tst)(\d\d)(rss|crd|tms|ids)\.csv$")
_LONGTERM_A5_SETS = frozenset({(25, "trn", 2), *((25, "tst", s) for s in range(6, 11))})


@dataclass(frozen=True, eq=False)
class Fingerprints:
    """Labelled WiFi fingerprints.

    Attributes
    ----------
    rssi_dbm : ndarray, shape (n, n_ap), float32
        RSS per fingerprint and access point; NaN = not heard.
    emitters : tuple of str, length n_ap
        Access point names, e.g. ``"WAP001"`` (the datasets do not publish BSSIDs).
    xy_m : ndarray, shape (n, 2), float64
        Position in metres of the dataset's frame (see the reader).
    floor : ndarray, shape (n,), int64
        Floor number as given by the dataset.
    building : ndarray, shape (n,), int64
        Building number as given (0 where the dataset has one building).
    t_s : ndarray, shape (n,), int64
        Time of the fingerprint, seconds since the epoch.
    phone_id : ndarray, shape (n,), int64
        Phone that took it, numbered as the reader documents.
    """

    rssi_dbm: NDArray[np.float32]
    emitters: tuple[str, ...]
    xy_m: NDArray[np.float64]
    floor: NDArray[np.int64]
    building: NDArray[np.int64]
    t_s: NDArray[np.int64]
    phone_id: NDArray[np.int64]

    def __len__(self) -> int:
        return int(self.rssi_dbm.shape[0])

    def rows(self, which: NDArray[np.intp] | NDArray[np.bool_]) -> Fingerprints:
        """The fingerprints of these rows (indices or a mask), same access points."""
        return replace(
            self,
            rssi_dbm=self.rssi_dbm[which],
            xy_m=self.xy_m[which],
            floor=self.floor[which],
            building=self.building[which],
            t_s=self.t_s[which],
            phone_id=self.phone_id[which],
        )

    def readings(self, row: int) -> list[RadioReading]:
        """What fingerprint ``row`` heard, as readings."""
        heard = ~np.isnan(self.rssi_dbm[row])
        return [
            RadioReading(self.emitters[j], float(self.rssi_dbm[row, j]))
            for j in np.flatnonzero(heard).tolist()
        ]


@dataclass(frozen=True, eq=False)
class LongTermFingerprints(Fingerprints):
    """Fingerprints of the UJI long-term set, with where each row comes from.

    Attributes
    ----------
    month : ndarray, shape (n,), int64
        Collection month 1..25.
    split : ndarray, shape (n,), str
        ``"trn"`` or ``"tst"``.
    set_no : ndarray, shape (n,), int64
        Set number within the month and split.
    point : ndarray, shape (n,), int64
        Point number within the set (test points repeat month after month).
    repetition : ndarray, shape (n,), int64
        Repetition number at that point.
    t_ms : ndarray, shape (n,), int64
        ``t_s`` with its milliseconds.
    """

    month: NDArray[np.int64]
    split: NDArray[np.str_]
    set_no: NDArray[np.int64]
    point: NDArray[np.int64]
    repetition: NDArray[np.int64]
    t_ms: NDArray[np.int64]


def _open_text(path: Path) -> IO[str]:
    if path.suffix == ".xz":
        return lzma.open(path, "rt", encoding="utf-8", newline="")
    return path.open(encoding="utf-8", newline="")


def read_ujiindoorloc(path: Path) -> Fingerprints:
    """Read a UJIIndoorLoc CSV (``trainingData.csv``, ``validationData.csv``, or ``.xz``).

    Parameters
    ----------
    path : Path
        The CSV file, plain or xz-compressed.

    Returns
    -------
    Fingerprints
        ``emitters`` are the ``WAP`` column names; ``rssi_dbm`` has NaN for ``+100``;
        ``xy_m`` is (LONGITUDE, LATITUDE) in Web-Mercator metres as given; ``floor``,
        ``building``, ``phone_id`` (PHONEID) and ``t_s`` (TIMESTAMP) as given.

    Raises
    ------
    ValueError
        A required column is missing or a value is not a number.
    """
    with _open_text(path) as f:
        header = [name.strip().strip('"') for name in f.readline().rstrip("\r\n").split(",")]
        missing = [c for c in _UJIINDOORLOC_COLUMNS if c not in header]
        if missing:
            raise ValueError(f"{path.name}: missing columns {', '.join(missing)}")
        data = np.loadtxt(f, delimiter=",", dtype=np.float64, ndmin=2)
    if data.shape[1] != len(header):
        raise ValueError(f"{path.name}: {data.shape[1]} values per row, {len(header)} names")
    ap = [j for j, name in enumerate(header) if name.startswith("WAP")]
    col = {name: data[:, header.index(name)] for name in _UJIINDOORLOC_COLUMNS}
    return Fingerprints(
        rssi_dbm=_not_heard_to_nan(data[:, ap]),
        emitters=tuple(header[j] for j in ap),
        xy_m=np.column_stack([col["LONGITUDE"], col["LATITUDE"]]),
        floor=col["FLOOR"].astype(np.int64),
        building=col["BUILDINGID"].astype(np.int64),
        t_s=col["TIMESTAMP"].astype(np.int64),
        phone_id=col["PHONEID"].astype(np.int64),
    )


def _not_heard_to_nan(rssi: NDArray[np.float64]) -> NDArray[np.float32]:
    out = rssi.astype(np.float32)
    out[rssi == NOT_HEARD_DBM] = np.nan
    return out


def _members(path: Path) -> Iterator[tuple[tuple[int, str, int], str, bytes]]:
    """((month, split, set), kind, bytes) of the long-term CSVs in a directory or a tar."""
    if path.is_dir() and not (path / "db").is_dir() and (path / "db.tar.xz").is_file():
        path = path / "db.tar.xz"
    if path.is_dir():
        for file in sorted(path.rglob("*.csv")):
            match = _LONGTERM_FILE.search(file.relative_to(path).as_posix())
            if match is not None:
                yield _set_key(match), match.group(4), file.read_bytes()
        return
    with tarfile.open(path, mode="r|*") as tar:  # streaming: one pass over the xz data
        for member in tar:
            match = _LONGTERM_FILE.search(member.name)
            f = tar.extractfile(member) if member.isfile() and match is not None else None
            if match is not None and f is not None:
                yield _set_key(match), match.group(4), f.read()


def _set_key(match: re.Match[str]) -> tuple[int, str, int]:
    return int(match.group(1)), match.group(2), int(match.group(3))


def read_uji_longterm(
    path: Path, month: int | None = None, split: Literal["trn", "tst"] | None = None
) -> LongTermFingerprints:
    """Read the UJI long-term WiFi set, or the part of one month and/or split.

    Parameters
    ----------
    path : Path
        ``db.tar.xz`` (any tar compression), the extracted ``db/`` directory or a
        directory above it, or the directory holding ``db.tar.xz``.
    month : int, optional
        Collection month 1..25; all months by default.
    split : {"trn", "tst"}, optional
        Training or test sets; both by default.

    Returns
    -------
    LongTermFingerprints
        Rows ordered by month, split (training first) and set. ``emitters`` are
        ``AP001..AP620``; ``xy_m`` in metres of the library frame; ``floor`` 3 or 5 as
        given; ``building`` 0; ``phone_id`` ``PHONE_GALAXY_S3`` or
        ``PHONE_GALAXY_A5_2017``; ``t_s`` / ``t_ms`` from the local clock time read as
        if it were UTC (the files carry no time zone; the phones were in Spain, CET/CEST).

    Raises
    ------
    ValueError
        No set matches, a set lacks one of its four files, or their row counts differ.
    """
    sets: dict[tuple[int, str, int], dict[str, bytes]] = {}
    for key, kind, data in _members(path):
        if (month is None or key[0] == month) and (split is None or key[1] == split):
            sets.setdefault(key, {})[kind] = data
    if not sets:
        raise ValueError(f"{path.name}: no set for month={month} split={split}")
    parts = [_read_longterm_set(key, files) for key, files in sorted(sets.items())]
    rssi = np.concatenate([p[0] for p in parts])
    crd = np.concatenate([p[1] for p in parts])
    t_ms = np.concatenate([p[2] for p in parts])
    ids = np.concatenate([p[3] for p in parts])
    labels = np.concatenate([p[4] for p in parts])  # (n, 4): month, split(1|2), set, phone
    n = rssi.shape[0]
    return LongTermFingerprints(
        rssi_dbm=rssi,
        emitters=tuple(f"AP{j + 1:03d}" for j in range(rssi.shape[1])),
        xy_m=np.ascontiguousarray(crd[:, :2]),
        floor=np.rint(crd[:, 2]).astype(np.int64),
        building=np.zeros(n, dtype=np.int64),
        t_s=t_ms // 1000,
        phone_id=labels[:, 3].copy(),
        month=labels[:, 0].copy(),
        split=np.where(labels[:, 1] == 1, "trn", "tst"),
        set_no=labels[:, 2].copy(),
        point=(ids // 100) % 1000,
        repetition=ids % 100,
        t_ms=t_ms,
    )


def _read_longterm_set(
    key: tuple[int, str, int], files: dict[str, bytes]
) -> tuple[
    NDArray[np.float32],
    NDArray[np.float64],
    NDArray[np.int64],
    NDArray[np.int64],
    NDArray[np.int64],
]:
    month, split, set_no = key
    label = f"{month:02d}/{split}{set_no:02d}"
    missing = {"rss", "crd", "tms", "ids"} - files.keys()
    if missing:
        raise ValueError(f"set {label}: missing {', '.join(sorted(missing))} file")
    rss = np.loadtxt(io.BytesIO(files["rss"]), delimiter=",", dtype=np.float64, ndmin=2)
    crd = np.loadtxt(io.BytesIO(files["crd"]), delimiter=",", dtype=np.float64, ndmin=2)
    ids = np.loadtxt(io.BytesIO(files["ids"]), dtype=np.int64, ndmin=1)
    t_ms = _clock_ms(files["tms"])
    n = rss.shape[0]
    if rss.shape[1] != _LONGTERM_N_AP or crd.shape != (n, 3) or ids.shape != (n,):
        raise ValueError(f"set {label}: rss {rss.shape}, crd {crd.shape}, ids {ids.shape}")
    if t_ms.shape != (n,):
        raise ValueError(f"set {label}: {t_ms.shape[0]} times for {n} rows")
    phone = PHONE_GALAXY_A5_2017 if key in _LONGTERM_A5_SETS else PHONE_GALAXY_S3
    labels = np.tile(np.array([month, 1 if split == "trn" else 2, set_no, phone]), (n, 1))
    return _not_heard_to_nan(rss), crd, t_ms, ids, labels.astype(np.int64)


def _clock_ms(tms_csv: bytes) -> NDArray[np.int64]:
    """``YYYYMMDDhhmmssSSS`` per line -> ms since the epoch, reading the clock as UTC.

    Computed field by field rather than parsed as ISO text, because the files hold a
    second 60 (``02/tst03``: ``...123260000``), which is carried into the next minute.
    """
    v = np.loadtxt(io.BytesIO(tms_csv), dtype=np.int64, ndmin=1)
    ymd, clock = np.divmod(v, 10**9)
    year, month_day = np.divmod(ymd, 10**4)
    month, day = np.divmod(month_day, 100)
    hour, rest = np.divmod(clock, 10**7)
    minute, rest = np.divmod(rest, 10**5)
    second, ms = np.divmod(rest, 1000)
    valid = (
        (year >= 1970) & (month >= 1) & (month <= 12) & (day >= 1) & (day <= 31)
        & (hour < 24) & (minute < 60) & (second <= 60)
    )  # fmt: skip
    if not valid.all():
        raise ValueError(f"not a YYYYMMDDhhmmssSSS time: {v[~valid][0]}")
    months = (year - 1970) * 12 + (month - 1)
    days = (months.astype("datetime64[M]").astype("datetime64[D]")).astype(np.int64) + day - 1
    t_ms: NDArray[np.int64] = ((days * 24 + hour) * 60 + minute) * 60_000 + second * 1000 + ms
    return t_ms
