"""Physical constants and unit conversions (CGS: cm, g, s, dyne).

KES measurements come in gram-force units: stress in gf/cm, bending moment in
gf·cm/cm, shear force in gf/cm. ``G`` converts gram-force to dyne.
"""

from __future__ import annotations

import numpy as np

#: Gram-force in dyne (g·cm/s²); also the magnitude of gravity in cm/s².
#: The paper prints 987.8 in its eqs. (2) and (15): a typo for 978.8 (docs/physics.md, units).
G: float = 978.80

#: Gravity vector (cm/s²), z up.
GRAVITY = np.array([0.0, 0.0, -G])

#: Degrees per radian (KES shear angles are in degrees).
DEG_PER_RAD: float = 180.0 / np.pi
