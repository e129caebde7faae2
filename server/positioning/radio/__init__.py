"""The WiFi/BLE side: radio maps and WKNN (``fingerprints``), matching a scan against the
map's own scans (``scan_matching``), a scan's fix for an engine (``scan_fixes``), what a
fix is worth (``fix_error``, ``accuracy_indicators``: the FAI of ``papers/000_*``) and
emitters from RSS at known places (``path_loss``)."""
