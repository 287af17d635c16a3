"""The model (docs/model.md): parameters, modal data, the equations of motion, closed forms."""

from worker.model.chain import (
    MAX_ASSEMBLED,
    MAX_CELLS,
    ChainParams,
    ChainSteadyState,
    ChainSystem,
    assemble_chain,
    bloch_exponent,
    chain_linear_transmittance_db,
    chain_steady_state,
    chain_transfer_transmittance_db,
    effective_mass,
    stop_bands,
    transfer_matrix,
)
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
    "MAX_ASSEMBLED",
    "MAX_CELLS",
    "MAX_MODES",
    "CellParams",
    "ChainParams",
    "ChainSteadyState",
    "ChainSystem",
    "SteadyState",
    "System",
    "assemble",
    "assemble_chain",
    "betas",
    "bloch_exponent",
    "chain_linear_transmittance_db",
    "chain_steady_state",
    "chain_transfer_transmittance_db",
    "effective_mass",
    "linear_transmittance_db",
    "mode_means",
    "mode_shape",
    "pinned_max_re",
    "pinned_transmittance_db",
    "rayleigh_constants",
    "steady_state",
    "stop_bands",
    "tip_values",
    "transfer_matrix",
]
