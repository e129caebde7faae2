"""The magnetic field as evidence: a floor's field map (``field_grid``), distances between
a walk's magnitudes and the map's (``sequence_distance``; both compiled for the particle
filter in ``magnetic_kernels``), and wireless-aided profile matching
(``profile_matching``, ``papers/000_*``)."""
