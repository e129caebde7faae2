"""The WiFi/BLE side: radio maps and WKNN (``fingerprints``), matching a scan against the
map's own scans (``scan_matching``), the floor as a hidden Markov model over the site's
floors (``floor_hmm``), what a fix is worth (``fix_error``, ``accuracy_indicators``: the
FAI of ``papers/000_*``) and emitters from RSS at known places (``path_loss``). What an
engine makes of a scan is ``engines.shared.scan_fixes``."""
