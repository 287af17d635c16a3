"""A point's execution limits, stated once and light to import (no numpy, no numba): the
solver's ``PointLimits`` and the service's settings (``IMPACTCELL_POINT_*``) both read them."""

from __future__ import annotations

#: Wall-clock seconds one point may run by default, and the most a setting may allow.
POINT_WALL_S = 600.0
POINT_WALL_S_MAX = 86_400.0
#: Time steps (events for ``event``) one point may take by default, and the most allowed.
POINT_STEPS = 10**9
POINT_STEPS_MAX = 10**12
