"""What the engines share: how an engine is declared and driven (``spec``), what an engine
may know of a site (``site_maps``), a scan's fix for an engine, with the floor filter and
the barometer's floor changes (``scan_fixes``), the Kalman state of the PDR engines
(``pdr_kalman``) and the routes of the engines on the phone's steps (``phone_steps``)."""
