"""The research harness: replaying recorded datasets (ILC 2.0, IPIN, UJIIndoorLoc)
through the engines, PDR evaluation, plots and benchmarks.

Nothing in the service imports it (an import contract in ``pyproject.toml``): the
service runs without it, and the harness only reads what the service's own layers offer.
"""
