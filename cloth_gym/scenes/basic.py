"""Basic scenes used by the demo, the benchmark and the numerics reports."""

from __future__ import annotations

from ..sim import ForceOptions, Rectangle, build_cloth
from ..sim.model import Model
from ..sim.obstacles import Box, Plane


def hanging_cloth(material="thick_cotton", size_cm: float = 20.0, sigma: float = 1.0,
                  model: str = "kes", height_cm: float | None = None) -> Model:
    """A square (warp along x) lying flat at ``height_cm`` (default: its size), held by the two
    corners of its far weft edge (j = -1). No obstacles: every force but contact."""
    h = size_cm if height_cm is None else height_cm
    m = build_cloth(Rectangle(size_cm, size_cm), material, sigma=sigma, options=ForceOptions.paper(model=model),
                    origin=(0, 0, h))
    return m.with_pinned([m.index(0, -1), m.index(-1, -1)])


def tablecloth(material="thick_cotton", size_cm: float = 40.0, table_cm: float = 20.0, sigma: float = 1.0,
               drop_cm: float = 10.0, model: str = "kes", friction: float | None = None) -> Model:
    """The paper's tablecloth: a ``size_cm`` square released flat ``drop_cm`` above a square table
    of side ``table_cm`` (top at z = 0, a solid block down to the floor at z = −80 cm).
    Obstacles: the table (friction ``friction``, default the material's) and the floor."""
    table = Box((0.0, 0.0, -40.0), (table_cm / 2, table_cm / 2, 40.0), friction=friction)
    floor = Plane((0.0, 0.0, -80.0), (0.0, 0.0, 1.0))
    return build_cloth(Rectangle(size_cm, size_cm), material, sigma=sigma, options=ForceOptions.paper(model=model),
                       origin=(0, 0, drop_cm + 0.1), obstacles=[table, floor], contact_thickness=0.1)
