"""Map building as pure steps: survey and crowdsourced points in, radio and magnetic maps out.

``map_set`` is the one builder (what a site has in, the map set every engine reads out):
gridding of survey points (``gridding``, ``matrices``, ``survey_points``), per-device RSS
offsets (``device_offsets``), the fix-error table (``fix_calibration``) and the FAI maps
(``fai_maps``), magnetic grids (``magnetic_gridding``). Crowdsourced walks
(``papers/003_*`` IV; ``walk_contribution``): inertial data selection (``selection``),
outer anchors (``anchors``, ``wifi_anchors``), segments (``segments``), alignment and
placement (``alignment``, ``placement``, ``labelled``), signature checks
(``signatures``). And what a floor's maps are worth (``map_quality``) and where to survey
next (``survey_plan``, ``papers/004_*`` Algorithm 1).
"""
