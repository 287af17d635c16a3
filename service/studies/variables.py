"""The one registry of axes and result variables: units, long names, symbols, groups, kinds.

Every place that names an axis or a result variable reads it here: the study schema (which
axes exist, in which order), the dataset (CF ``units`` and ``long_name``, how each variable is
stored), the plots (symbols for labels), the routes (default axes) and the regression suite
(which variables may be compared).

How a point ended is ``outcome``: a CF flag variable (int8, ``flag_values`` 0…4 and
``flag_meanings`` "linear periodic irregular unsettled failed", the order of
``worker.solvers.settings.OUTCOMES``), never missing. Records carry it as a string, chunk files
and datasets as its flag value; :func:`outcome_names` reads it back as strings.

Whether an irregular point may be transient chaos is ``may_be_transient``: a CF flag too (int8
on disk, ``flag_values`` 0 1, ``flag_meanings`` "not_flagged may_be_transient"; xarray reads it
as bool), with ``impacting_periods``, how long the impacting motion has lasted, beside it.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

import numpy as np

from worker.model import CellParams
from worker.physical import PhysicalCell
from worker.solvers.settings import OUTCOMES, PER_STOP

__all__ = [
    "AXES",
    "AXIS_PARAMETER",
    "CHAIN_VARIABLES",
    "FREQUENCY_AXES",
    "MODEL_AXES",
    "OUTCOMES",
    "PHYSICAL_AXES",
    "PHYSICAL_FIELDS",
    "PHYSICAL_VARIABLES",
    "STOP_VARIABLES",
    "SWEEP_VARIABLES",
    "VARIABLES",
    "AxisInfo",
    "Variable",
    "axis_symbol",
    "default_x",
    "flag_attrs",
    "outcome_attrs",
    "outcome_codes",
    "outcome_counts",
    "outcome_names",
    "result_values",
    "cell_coordinate",
    "stop_coordinate",
]


# --------------------------------------------------------------------------- axes

# Canonical axis order (the dataset's dimension order, independent of the file's key order).
# γ_r is last so that a chunk of consecutive points is a piece of one spectrum.
# The axes are CellParams' real-valued parameters (not the optional xi_b) plus ``cells`` (a
# chain's length) and ``gap`` (both stops at once): the chain first, the stops, then the
# parameters in CellParams' order.
# an axis that is not a parameter -> the rule it follows
AXIS_PARAMETER: dict[str, str] = {"gap": "g1", "restitution": "e1"}
_CELL_AXES = tuple(
    f.name
    for f in dataclasses.fields(CellParams)
    if not ({"choices", "integer", "boolean", "optional"} & set(f.metadata))
)
MODEL_AXES: tuple[str, ...] = (
    "cells",  # a chain's length N (docs/chains.md); not a CellParams field
    "gap",
    "g1",
    "g2",
    "restitution",  # both stops' e at once, as gap sets both clearances
    "e1",
    "e2",
    *(a for a in _CELL_AXES if a not in ("g1", "g2", "e1", "e2", "gamma_r")),
    "gamma_r",
)
# The SI fields are PhysicalCell's own, so the study schema cannot drift from the cell.
PHYSICAL_FIELDS: tuple[str, ...] = tuple(f.name for f in dataclasses.fields(PhysicalCell))
PHYSICAL_AXES: tuple[str, ...] = (*PHYSICAL_FIELDS, "frequency_hz")
# Axes a spectrum runs along (the x of a transmittance plot or a bandgap map), preferred first.
FREQUENCY_AXES: tuple[str, ...] = ("gamma_r", "frequency_hz")


@dataclass(frozen=True)
class AxisInfo:
    """What a coordinate is: CF ``units`` and ``long_name``, and how figures label it."""

    units: str
    long_name: str
    symbol: str = ""  # in labels and legends ("" = the name itself)
    definition: str = ""  # shown after the symbol in axis labels: "γ_r = Ω/ω_b"
    label: str = ""  # an axis label used instead of symbol and definition ("frequency")


AXES: dict[str, AxisInfo] = {
    "gamma_r": AxisInfo("1", "excitation frequency gamma_r = Omega / omega_b", "γ_r", "Ω/ω_b"),
    "cells": AxisInfo("1", "number of cells N of the chain (1: the unit cell)", "N"),
    "cell": AxisInfo("1", "cell index j along the chain, 1 at the base", "cell j"),
    "gap": AxisInfo("1", "clearance to both stops g1 = g2, in units of B", "g̃", "g̃₁ = g̃₂"),
    "g1": AxisInfo("1", "clearance to stop 1, in units of B", "g̃₁"),
    "g2": AxisInfo("1", "clearance to stop 2, in units of B", "g̃₂"),
    "restitution": AxisInfo("1", "coefficient of restitution at both stops e1 = e2 (Newton)",
                            "e", "e₁ = e₂"),
    "e1": AxisInfo("1", "coefficient of restitution at stop 1 (Newton)", "e₁"),
    "e2": AxisInfo("1", "coefficient of restitution at stop 2 (Newton)", "e₂"),
    "theta": AxisInfo("1", "mass ratio theta = rho A l / m_o", "θ"),
    "sigma": AxisInfo("1", "beam stiffness parameter sigma = EI / (rho A l^4 omega_b^2)", "σ"),
    "gamma_s": AxisInfo("1", "inverse mass frequency gamma_s = omega_b / omega_m", "γ_s",
                        "ω_b/ω_m"),
    "xi": AxisInfo("1", "damping ratio xi", "ξ"),
    "frequency_hz": AxisInfo("Hz", "excitation frequency", "f", label="frequency"),
    "length_m": AxisInfo("m", "beam free length", "length"),
    "width_m": AxisInfo("m", "beam width", "width"),
    "thickness_m": AxisInfo("m", "beam thickness", "thickness"),
    "density_kg_m3": AxisInfo("kg m-3", "beam density", "density"),
    "youngs_modulus_pa": AxisInfo("Pa", "beam Young's modulus", "E"),
    "outer_mass_kg": AxisInfo("kg", "outer mass", "outer mass"),
    "spring_n_m": AxisInfo("N m-1", "spring stiffness", "spring stiffness"),
    "damping_ratio": AxisInfo("1", "damping ratio of the outer dashpot", "damping ratio"),
    "gap_m": AxisInfo("m", "clearance to both stops", "gap"),
    "gap1_m": AxisInfo("m", "clearance to stop 1", "gap 1"),
    "gap2_m": AxisInfo("m", "clearance to stop 2", "gap 2"),
    "base_amplitude_m": AxisInfo("m", "base displacement amplitude U_g", "U_g"),
    "base_acceleration_m_s2": AxisInfo("m s-2", "base acceleration amplitude",
                                       "base acceleration"),
    "stop": AxisInfo("1", "stop index (1 or 2)", "stop"),
    "initial": AxisInfo("1", "initial state the point (or its sweep line) started from: rest, "
                        "linear (closed-form steady state of the cell without stops, at "
                        "tau = 0) or random-<k> (seeded, around the linear one)", "initial"),
    "direction": AxisInfo("1", "sweep direction along the swept axis: up (increasing values) "
                          "or down; each point starts from the final state of the previous "
                          "point of its line", "direction"),
}  # fmt: skip


def axis_symbol(name: str) -> str:
    """The symbol of an axis in labels and legends (its name when it has none)."""
    info = AXES.get(name)
    return info.symbol if info is not None and info.symbol else name


def default_x(dims: Iterable[Any]) -> str | None:
    """The frequency axis among ``dims`` (``gamma_r``, else ``frequency_hz``), or None."""
    present = {str(d) for d in dims}
    return next((a for a in FREQUENCY_AXES if a in present), None)


# --------------------------------------------------------------------------- result variables


@dataclass(frozen=True)
class Variable:
    """A result variable: the outputs group that stores it, how it is stored, CF attributes."""

    group: str  # outputs group ("" = always stored)
    kind: str  # float | int | maskint | bool | str | flag (int8 CF flag of OUTCOMES)
    units: str
    long_name: str
    mask: bool = True  # missing where the point failed
    flags: tuple[str, ...] = ()  # CF flag_meanings of a bool or flag variable, value 0 first


# Result variables, in the order they appear in the dataset.
VARIABLES: dict[str, Variable] = {
    "transmittance_db": Variable(
        "transmittance", "float", "dB",
        "transmittance Gamma = 20 log10(A_s / (theta gamma_s)) (Eq. 32); the mean over "
        "measurement windows for irregular and unsettled points",
    ),
    "transmittance_db_se": Variable(
        "transmittance", "float", "dB",
        "standard error of the transmittance of an irregular or unsettled point (batch means "
        "over measurement windows); missing for linear and periodic points",
    ),
    "transmittance_linear_db": Variable(
        "transmittance", "float", "dB",
        "linear reference Gamma_lin: transmittance of the same cell with the stops removed "
        "(closed form, docs/model.md section 7); a property of the cell, kept at failed points; "
        "missing where no closed form exists (undamped resonance)",
        mask=False,
    ),
    "impact_effect_db": Variable(
        "transmittance", "float", "dB",
        "impact effect Gamma - Gamma_lin: what the stops change; negative where impacts add "
        "attenuation, exactly 0 at linear (impact-free) points; missing where either is",
    ),
    "amplitude": Variable(
        "transmittance", "float", "1",
        "displacement amplitude A_s of the outer mass in units of B = U_g / (theta gamma_s)",
    ),
    "theta_eff": Variable(
        "effective_mass", "float", "1",
        "effective mass ratio theta_eff = M_eff / (m_o + rho A l): force over acceleration at "
        "the driving frequency, from the first harmonics at gamma_r (Eq. 35); the effective "
        "mass at every point, impacting or not (docs/model.md section 6)",
    ),
    "theta_eff_slope": Variable(
        "effective_mass", "float", "1",
        "phase-portrait ratio theta_ps = (kappa - theta <s_b_dot s_dot> / <s_dot^2>) / "
        "(1 + theta): the least-squares slope of the velocity phase portrait (the paper's "
        "Figure 6 panels ii), every harmonic weighted by its velocity power; equal to theta_eff "
        "where the motion is harmonic (linear points), not an effective mass at impacting "
        "points; missing if undefined",
    ),
    "outcome": Variable(
        "response", "flag", "1",
        "how the point ended: linear (closed-form steady state, impact-free), periodic "
        "(confirmed orbit with impacts), irregular (converged window statistics), unsettled "
        "(period budget ran out first) or failed",
        mask=False,
    ),
    "may_be_transient": Variable(
        "response", "bool", "1",
        "irregular point where the impact-free response is admissible too: its impacting "
        "motion may be transient chaos that dies out into that response (transmittance "
        "Gamma_lin), so its transmittance is not a settled value",
        mask=False, flags=("not_flagged", "may_be_transient"),
    ),
    "impacting_periods": Variable(
        "response", "maskint", "1",
        "excitation periods the impacting motion of a may_be_transient point has lasted: its "
        "run from the point's start to the irregular claim, impacts continuing into the last "
        "quarter of its final window; missing elsewhere",
    ),
    "response_period": Variable(
        "response", "maskint", "1",
        "response period in excitation periods (1 = linear, p = periodic orbit, "
        "0 = irregular or unsettled)",
    ),
    "impacts_per_period": Variable(
        "response", "float", "1",
        "contact episodes begun at stop per excitation period (a rebound sequence is one): "
        "exact over the orbit of a periodic point, the mean over the stationary span's "
        "windows at an irregular or unsettled one",
    ),
    "impacts_per_period_se": Variable(
        "response", "float", "1",
        "standard error of impacts_per_period at an irregular or unsettled point (the windows "
        "as batches); missing elsewhere",
    ),
    "contact_fraction": Variable(
        "response", "float", "1",
        "fraction of the period the tip spends on stop (method event: stuck on it; time "
        "stepping: the steps whose impulse holds it there): exact over the "
        "orbit of a periodic point, 0 at a linear one, the mean over the stationary span's "
        "windows at an irregular or unsettled one",
    ),
    "contact_fraction_se": Variable(
        "response", "float", "1",
        "standard error of contact_fraction at an irregular or unsettled point (the windows as "
        "batches); missing elsewhere",
    ),
    "impact_velocity": Variable(
        "response", "float", "1",
        "mean velocity of the tip towards stop at the impacts counted there (in units of B "
        "per unit tau); missing where the stop had none",
    ),
    "impact_velocity_se": Variable(
        "response", "float", "1",
        "standard error of impact_velocity at an irregular or unsettled point (the ratio "
        "estimator's, the windows as batches); missing elsewhere and where fewer than two "
        "windows had impacts at stop",
    ),
    "impact_energy": Variable(
        "response", "float", "1",
        "energy dissipated by the impacts at stop per excitation period, the sum over its "
        "impulses of (v-^2 - v+^2) / (2 G) with v the tip velocity just before and after "
        "(plastic: v-^2 / (2 G)), in units of rho A l B^2 omega_b^2 (docs/model.md section "
        "6): exact over the orbit of a periodic point, 0 at a linear one, the mean over the "
        "stationary span's windows at an irregular or unsettled one",
    ),
    "impact_energy_se": Variable(
        "response", "float", "1",
        "standard error of impact_energy at an irregular or unsettled point (the windows as "
        "batches); missing elsewhere",
    ),
    "impact_energy_share": Variable(
        "response", "float", "1",
        "share of the energy the cell dissipates per period that the impacts take: their energy "
        "over the work of the forcing, which the dashpots and the impacts dissipate (full "
        "coupling only; missing in paper coupling, which has no energy balance, and where "
        "the forcing does no work); 0 at a linear point",
    ),
    "floquet_multiplier": Variable(
        "response", "float", "1",
        "modulus of the dominant Floquet multiplier of the steady response over its period: "
        "the monodromy matrix's spectral radius (finite differences) or exact (linear points, "
        "zero gaps); missing where not computed (no Jacobian, a check costlier than twice the "
        "periods run, early stop off) and at irregular, unsettled and failed points",
    ),
    "periods": Variable("response", "int", "1", "excitation periods simulated", mask=False),
    "steps": Variable("response", "int", "1", "time steps taken", mask=False),
    "peak_impulse": Variable(
        "response", "float", "1",
        "largest contact impulse in a period (non-dimensional; time stepping: the largest "
        "step impulse): over the orbit of a periodic point, the stationary span's windows at "
        "an irregular or unsettled one",
    ),
    "contact_steps": Variable(
        "contact", "int", "1", "time steps that needed a contact solve", mask=False
    ),
    "coarse_steps": Variable(
        "contact", "int", "1", "free-flight coarse steps taken whole (exponential)", mask=False
    ),
    "steady_period": Variable(
        "contact", "maskint", "1", "period index at which the steady state was detected"
    ),
    "failed": Variable("", "bool", "1", "point failed (see reason); its results are missing",
                       mask=False),
    "reason": Variable("", "str", "1", "why the point failed or is unsettled, or a caveat of an "
                       "irregular point; empty otherwise", mask=False),
    "wall_s": Variable("", "float", "s", "wall-clock time of the point's kernel", mask=False),
}  # fmt: skip


# Variables a physical study's dataset derives from the points (not reported by a point): in
# metres, with the length unit B = U_g / (theta gamma_s) of each point (docs/model.md section 8).
PHYSICAL_VARIABLES: dict[str, Variable] = {
    "amplitude_m": Variable(
        "transmittance", "float", "m",
        "displacement amplitude of the outer mass in metres, amplitude times B = U_g / "
        "(theta gamma_s) (docs/model.md section 8)",
    ),
}  # fmt: skip


# Variables of studies with initial states or a sweep (docs: README "Study files"). Not in
# VARIABLES: a study without either has exactly the datasets it always had.
# ``started_from`` is reported by each point of a sweep line (chunk files keep it);
# ``responses`` is derived when the dataset is assembled (service.studies.coexistence).
SWEEP_VARIABLES: dict[str, Variable] = {
    "started_from": Variable(
        "", "str", "1",
        "state the point started from: initial (the study's initial state: the first point of "
        "a sweep line) or previous (the final state of the previous point of its sweep line, "
        "at forcing phase 0); empty where unknown (a failed task, a pending point)",
        mask=False,
    ),
    "responses": Variable(
        "", "int", "1",
        "number of distinct steady responses found at this grid point across initial states "
        "and sweep directions: distinct by outcome, response period and transmittance (more "
        "than coexistence_tol_db apart; irregular ones more than 3 combined standard errors); "
        "failed, unsettled and pending points are not counted",
        mask=False,
    ),
}  # fmt: skip


# Per-cell variables of a chain study (docs/chains.md), over a ``cell`` dimension of the
# study's largest N: missing beyond a point's own N. Not in VARIABLES: a study of unit cells
# has exactly the datasets it always had.
CHAIN_VARIABLES: dict[str, Variable] = {
    "cell_transmittance_db": Variable(
        "transmittance", "float", "dB",
        "transmittance Gamma_j = 20 log10(A_j / (theta gamma_s)) of cell j's outer mass: "
        "exact over the orbit of a periodic point, the closed form at a linear one; missing "
        "at irregular, unsettled and failed points (not proven) and beyond the point's N",
    ),
    "cell_transmittance_linear_db": Variable(
        "transmittance", "float", "dB",
        "linear reference Gamma_j,lin of cell j: the same chain with the stops removed "
        "(closed form, docs/model.md section 11); missing beyond the point's N and where no "
        "closed form exists",
        mask=False,
    ),
}  # fmt: skip


#: Result variables with one value per stop (a trailing ``stop`` dimension of 2).
STOP_VARIABLES: tuple[str, ...] = PER_STOP


# --------------------------------------------------------------------------- stored values

#: An integer result a point does not have (``maskint``: e.g. no response period), in records.
MISSING_INT = -1


def result_values(
    name: str, values: Any, failed: np.ndarray | None = None
) -> tuple[np.ndarray, dict[str, Any]]:
    """A result variable as every dataset stores it: values of its kind's dtype (``maskint``
    and, at failed points, masked floats as NaN: NetCDF fill values on disk) and its CF
    attributes. One place for what a study's results and a point-store query both hold."""
    var = VARIABLES[name] if name in VARIABLES else CHAIN_VARIABLES[name]
    a = np.asarray(values)
    if var.kind in ("float", "maskint"):
        a = a.astype(np.float64)
        if var.kind == "maskint":
            a[a == MISSING_INT] = np.nan
        if var.mask and failed is not None:
            a[failed] = np.nan
    elif var.kind == "int":
        a = a.astype(np.int64)
    elif var.kind == "bool":
        a = a.astype(bool)
    elif var.kind == "flag":
        a = a.astype(np.int8)
    else:
        a = np.array([str(x) for x in a], dtype=object)
    attrs: dict[str, Any] = {"units": var.units, "long_name": var.long_name}
    if var.kind == "flag":
        attrs.update(outcome_attrs())
    attrs.update(flag_attrs(var))
    return a, attrs


def stop_coordinate() -> tuple[str, np.ndarray, dict[str, str]]:
    """The ``stop`` coordinate (1, 2) of per-stop variables such as ``impacts_per_period``."""
    info = AXES["stop"]
    return ("stop", np.array([1, 2], dtype=np.int8), {"units": info.units,
                                                       "long_name": info.long_name})  # fmt: skip


def cell_coordinate(n: int) -> tuple[str, np.ndarray, dict[str, str]]:
    """The ``cell`` coordinate (1 … n) of a chain study's per-cell variables."""
    info = AXES["cell"]
    return ("cell", np.arange(1, n + 1, dtype=np.int32), {"units": info.units,
                                                         "long_name": info.long_name})  # fmt: skip


# --------------------------------------------------------------------------- the outcome flag


def flag_attrs(var: Variable) -> dict[str, Any]:
    """The CF flag attributes of a bool variable with ``flags`` (values 0, 1, …)."""
    if not var.flags:
        return {}
    return {
        "flag_values": np.arange(len(var.flags), dtype=np.int8),
        "flag_meanings": " ".join(var.flags),
    }


def outcome_attrs() -> dict[str, Any]:
    """The CF flag attributes of ``outcome`` (flag values are the indices of ``OUTCOMES``)."""
    return {
        "flag_values": np.arange(len(OUTCOMES), dtype=np.int8),
        "flag_meanings": " ".join(OUTCOMES),
    }


def outcome_codes(names: Iterable[Any]) -> np.ndarray:
    """Flag values (int8) of outcome names; an unknown name is a ``ValueError``."""
    index = {k: i for i, k in enumerate(OUTCOMES)}
    out = []
    for n in names:
        try:
            out.append(index[str(n)])
        except KeyError:
            raise ValueError(f"outcome must be one of {', '.join(OUTCOMES)}, got {n!r}") from None
    return np.array(out, dtype=np.int8)


def outcome_names(da: Any) -> np.ndarray:
    """Outcome names (str array, same shape) of an ``outcome`` flag variable or array.

    The names come from the variable's ``flag_values``/``flag_meanings`` when it has them
    (a file read back), else from ``OUTCOMES``.
    """
    values = np.asarray(getattr(da, "values", da))
    attrs = getattr(da, "attrs", {}) or {}
    meanings = str(attrs.get("flag_meanings", "")).split()
    flags = np.asarray(attrs.get("flag_values", np.arange(len(meanings))), dtype=np.int64).ravel()
    table = dict(zip(flags.tolist(), meanings, strict=False)) if meanings else {}
    if not table:
        table = dict(enumerate(OUTCOMES))
    codes = values.astype(np.int64)
    out = np.full(values.shape, "", dtype=object)
    for code, name in table.items():
        out[codes == code] = name
    return out.astype(str)


def outcome_counts(names: Any) -> dict[str, int]:
    """How many points ended with each outcome (every outcome listed, zeros included)."""
    arr = np.asarray(names).astype(str).ravel()
    return {k: int(np.sum(arr == k)) for k in OUTCOMES}
