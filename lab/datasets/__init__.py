"""Readers of recorded public datasets.

Each reader turns files into the service's own values — a ``Walk`` (scans, motion
samples and ground truth, with event views from ``server.positioning.model.events``, so a
replayed trace and live phone traffic go through the same code) or plain arrays of
fingerprints — with units in the field names (``t_ms``, ``x_m``, ``rssi_dbm``). What a
reader could not read goes into its report (``server.storage.text_records.ParseReport``),
not into the walk.

- ``ilc``: Indoor Location Competition 2.0 sites, floors and floor plans (``read_site``);
  one of its phone traces is read by the service's own ``server.storage.ilc_trace_format``
  (``read_trace``; strict ``parse_trace_text`` for uploads).
- ``ipin``: the IPIN 2023 Track 3 venue (``read_venue``); ``ipin_log``: one GetSensorData
  log (``read_log``); ``ipin_frame``: the venue's local metric frame.
- ``uji``: UJIIndoorLoc and the UJI long-term WiFi fingerprints
  (``read_ujiindoorloc``, ``read_uji_longterm``).

Readers do file I/O and nothing else: no web framework, no database, no settings. The data
itself is not part of the project; tests and benchmarks read it from ``../shared/data/``
relative to the project root.
"""
