"""Floor plans: the GeoJSON plan format (``geojson_format``), its checks
(``geojson_validation``) and the walkable area and walls it builds (``geojson_plan``), the
walkable raster and the wall-crossing test (``floor_plan``, ``wall_index``, compiled in
``move_test_kernels``), the navigation graph of reference points (``navigation_graph``)
and the anchors a plan marks (``anchors``)."""
