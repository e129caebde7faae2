"""Request and response bodies of the public API (the wire format), one module per
resource: ``sites`` (sites, buildings, floors, plans), ``events`` (radio readings and the
typed events of batches and uploads), ``sessions`` (sessions, batches, fixes, the live
socket's batch), ``maps`` (surveys, radio and magnetic maps, device offsets),
``map_quality``, ``uploads``, ``locate``, ``keys``, ``errors``; ``common`` holds the
scalar types and base models they share.

Units are in the names: metres (``_m``), radians clockwise from north (``_rad``),
dBm (``rssi_dbm``), µT (``_ut``); ``t`` is milliseconds since the epoch (phone clock).
Floors on the wire are integer levels; buildings and floors are ids.
"""
