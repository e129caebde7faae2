"""Everything synthetic about one site, drawn from one seed: building, radio, magnetism."""

from __future__ import annotations

from dataclasses import dataclass

from client_sim.building import SyntheticBuilding, synthesize_building
from client_sim.magnetic import MagneticField, synthesize_magnetic
from client_sim.radio import RadioEnvironment, synthesize_radio
from client_sim.seeding import stream


@dataclass(frozen=True, eq=False)
class SyntheticWorld:
    building: SyntheticBuilding
    radio: RadioEnvironment
    magnetic: MagneticField


def synthesize_world(seed: int, building: SyntheticBuilding | None = None) -> SyntheticWorld:
    """The default building (or ``building``) with its radio environment and magnetic
    field, each from its own stream of ``seed``."""
    b = building if building is not None else synthesize_building(stream(seed, "building"))
    return SyntheticWorld(
        building=b,
        radio=synthesize_radio(b, stream(seed, "radio")),
        magnetic=synthesize_magnetic(b, stream(seed, "magnetic")),
    )
