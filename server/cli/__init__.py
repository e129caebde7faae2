"""The ``indoorpos`` command: one module per command group, each command parsing its
arguments, calling the services and printing what they give back.

``main`` builds the command (``main.app``, the console script's entry point): ``service``
(serve, worker, migrate, openapi), ``keys``; ``output`` holds the console. Importing a
module of this package runs no plugin: only ``main`` loads them.

Other distributions add their commands through the ``indoorpos.commands`` entry point
group: each entry point names a function taking this ``app``. The research harness
(``indoorpos-lab``) adds ``demo``, ``simulate``, ``evaluate``, ``bench`` and
``plan-survey``; the service itself never imports it.
"""
