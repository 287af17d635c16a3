"""The model (docs/model.md): parameters, modal data, the equations of motion, closed forms."""

from worker.model.modal import betas, mode_means, mode_shape, tip_values
from worker.model.params import COUPLINGS, MAX_MODES, CellParams
from worker.model.references import (
    SteadyState,
    linear_transmittance_db,
    pinned_max_re,
    pinned_transmittance_db,
    steady_state,
)
from worker.model.system import System, assemble, rayleigh_constants

__all__ = [
    "COUPLINGS",
    "MAX_MODES",
    "CellParams",
    "SteadyState",
    "System",
    "assemble",
    "betas",
    "linear_transmittance_db",
    "mode_means",
    "mode_shape",
    "pinned_max_re",
    "pinned_transmittance_db",
    "rayleigh_constants",
    "steady_state",
    "tip_values",
]
