"""The research harness: replaying recorded datasets (ILC 2.0, IPIN, UJIIndoorLoc)
through the engines, PDR evaluation, plots, and the benchmarks of the particle filter
(``particle_bench``) and of the service under load (``load_bench``).

Nothing in the service imports it (an import contract in ``pyproject.toml``): the
service runs without it, and the harness only reads what the service's own layers offer,
through the services or, as a phone would, through the api's wire format.
"""
