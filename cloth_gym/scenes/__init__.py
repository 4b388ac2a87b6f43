"""Scene builders (a small, documented function each).

* :mod:`.basic`: the hanging cloth and the bare tablecloth model (demo, benchmarks);
* :mod:`.cantilever`: the cantilever bending test of a clamped strip, with its continuum reference;
* :mod:`.paper`: the paper's validation scenes (drape test, tablecloth, falling ribbon)
  as :class:`Scene` data, and :func:`run_until_settled`.
"""

from .basic import hanging_cloth, tablecloth
from .cantilever import cantilever_strip, cantilever_tip_drop, heavy_elastica_tip_drop, settle_cantilever
from .paper import (DRAPE_GEOMETRIES, Scene, SettleResult, drape_metrics, drape_test, make_integrator, ribbon,
                    run_until_settled, settle_threshold, table_corner_strain, tablecloth_scene)

__all__ = [
    "hanging_cloth", "tablecloth", "Scene", "SettleResult", "DRAPE_GEOMETRIES", "drape_test",
    "tablecloth_scene", "ribbon", "make_integrator", "run_until_settled", "settle_threshold",
    "table_corner_strain", "drape_metrics", "cantilever_strip", "settle_cantilever", "cantilever_tip_drop",
    "heavy_elastica_tip_drop",
]
