"""Readers of recorded public datasets.

Each reader turns files into the service's own values — the events of
``server.positioning.events`` (so a replayed trace and live phone traffic go through the
same code) or plain arrays of fingerprints — with units in the field names
(``t_ms``, ``x_m``, ``rssi_dbm``).

- ``ilc``: Indoor Location Competition 2.0 phone traces, floor information and floor
  plans (``read_trace``, ``read_site``).
- ``uji``: UJIIndoorLoc and the UJI long-term WiFi fingerprints
  (``read_ujiindoorloc``, ``read_uji_longterm``).

Readers do file I/O and nothing else: no web framework, no database, no settings. The data
itself is not part of the project; tests and benchmarks read it from ``../shared/data/``
relative to the project root.
"""
