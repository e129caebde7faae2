"""Client simulator: synthetic buildings, radio and magnetic fields, walkers, and an
HTTP/WebSocket client that provisions a site and load-tests a deployed indoorpos stack.

Modules: ``building`` (floor plans and walkable graph), ``radio`` (WiFi/BLE path loss),
``magnetic`` (indoor field), ``world`` (all three from one seed), ``survey`` (survey
points), ``walker`` (events and truth of a pedestrian), ``api`` (HTTP and live-socket
client), ``site`` (provisioning), ``run`` (``run_walkers``: load and accuracy run),
``seeding`` (random streams). It imports nothing from ``server``: it speaks the wire
format only.
"""
