"""The engines by name: what a session, a site's settings and the harness look engines up in."""

from __future__ import annotations

from server.positioning.engines import (
    auto,
    everywhere_ekf,
    fai_ekf,
    map_markov,
    pf_magnetic,
    step_ekf,
    two_stage_ekf,
    wknn,
)
from server.positioning.engines.shared.spec import Engine

ENGINES: dict[str, Engine] = {
    spec.name: spec
    for spec in (
        auto.SPEC,
        everywhere_ekf.SPEC,
        fai_ekf.SPEC,
        map_markov.SPEC,
        pf_magnetic.SPEC,
        step_ekf.SPEC,
        two_stage_ekf.SPEC,
        wknn.SPEC,
    )
}


# engines that read the floors' reference-point graphs (``SiteMaps.graphs``), built for
# their sessions only
NEEDS_GRAPHS = frozenset({map_markov.SPEC.name})


def get_engine(name: str) -> Engine:
    """The registry entry of engine ``name``.

    Raises
    ------
    KeyError
        When no engine has that name; the message lists the known engines.
    """
    try:
        return ENGINES[name]
    except KeyError:
        known = ", ".join(sorted(ENGINES))
        raise KeyError(f"unknown engine {name!r}; known engines: {known}") from None
