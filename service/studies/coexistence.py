"""Coexisting responses: how many distinct steady responses a grid point has.

A study with several initial states or a sweep in both directions computes each grid point
more than once (its ``initial`` and ``direction`` dimensions). Where the cell has coexisting
responses, those computations end on different ones. :func:`count_responses` counts the
distinct responses per grid point; the results dataset stores it as ``responses``.
"""

from __future__ import annotations

import numpy as np
import xarray as xr

from service.studies.variables import SWEEP_VARIABLES, outcome_names

__all__ = ["COUNTED", "EXTRA_DIMS", "IRREGULAR_SE", "count_responses"]

#: The dimensions a grid point is computed along more than once (in a dataset's order).
EXTRA_DIMS: tuple[str, ...] = ("initial", "direction")
#: Outcomes that are responses found (failed and unsettled points found none; pending points
#: are failed with reason ``pending``).
COUNTED: tuple[str, ...] = ("linear", "periodic", "irregular")
#: Two irregular responses are one when their Γ differ by less than this many combined
#: standard errors ``sqrt(se_a² + se_b²)``.
IRREGULAR_SE = 3.0
# Grid points compared at once (bounds the (points, M, M) comparison arrays).
_BLOCK_PAIRS = 1_000_000


def count_responses(ds: xr.Dataset, tol_db: float) -> xr.DataArray:
    """Number of distinct responses at each grid point, across ``initial`` and ``direction``.

    Two computations of a grid point found the same response when they have the same
    outcome (``linear``, ``periodic`` or ``irregular``; an irregular response is never the
    same as a periodic one) and

    * linear or periodic: the same ``response_period`` and transmittances within ``tol_db``
      (``|Γ_a − Γ_b| <= tol_db``);
    * irregular: ``|Γ_a − Γ_b| < 3 sqrt(se_a² + se_b²)`` (``transmittance_db_se``; within
      ``tol_db`` where a standard error is missing).

    "The same" is closed transitively (responses chained by such steps are one), so the count
    does not depend on the order of the computations. Failed, unsettled and pending points are
    not counted: a grid point where every computation failed has 0 responses. Without
    ``transmittance_db`` (``outputs.transmittance`` off) responses differ by outcome and
    period only.

    Parameters
    ----------
    ds : xarray.Dataset
        A results dataset with ``outcome`` (and ideally ``response_period``,
        ``transmittance_db``, ``transmittance_db_se``).
    tol_db : float
        The transmittance tolerance (dB), ``outputs.coexistence_tol_db`` of the study.

    Returns
    -------
    xarray.DataArray
        ``responses`` (int64) over the grid dimensions (every dimension of ``outcome`` but
        ``initial`` and ``direction``), with their coordinates.

    Raises
    ------
    ValueError
        The dataset has no ``outcome``, or ``tol_db`` is not a positive number.
    """
    if "outcome" not in ds:
        raise ValueError("counting responses needs the outcome variable (outputs.response)")
    if not np.isfinite(tol_db) or tol_db <= 0:
        raise ValueError(f"tol_db must be a positive number of dB, got {tol_db}")
    outcome = ds["outcome"]
    extra = [d for d in EXTRA_DIMS if d in outcome.dims]
    grid = [d for d in outcome.dims if d not in extra]
    order = [*grid, *extra]
    sizes = [outcome.sizes[d] for d in grid]
    n_grid = int(np.prod(sizes, dtype=np.int64))
    m = int(np.prod([outcome.sizes[d] for d in extra], dtype=np.int64))

    def flat(name: str) -> np.ndarray:
        if name not in ds:
            return np.full((n_grid, m), np.nan)
        a = ds[name].transpose(*order).values.astype(np.float64)
        return a.reshape(n_grid, m)

    names = outcome_names(outcome.transpose(*order)).reshape(n_grid, m)
    kind = np.full((n_grid, m), -1, dtype=np.int64)
    for code, name in enumerate(COUNTED):
        kind[names == name] = code
    if "failed" in ds:
        kind[ds["failed"].transpose(*order).values.reshape(n_grid, m).astype(bool)] = -1
    period = flat("response_period")
    gamma = flat("transmittance_db")
    se = flat("transmittance_db_se")
    counts = np.zeros(n_grid, dtype=np.int64)
    block = max(1, _BLOCK_PAIRS // max(1, m * m))
    for a in range(0, n_grid, block):
        b = min(n_grid, a + block)
        counts[a:b] = _count_block(kind[a:b], period[a:b], gamma[a:b], se[a:b], tol_db)
    var = SWEEP_VARIABLES["responses"]
    attrs = {"units": var.units, "long_name": var.long_name, "coexistence_tol_db": float(tol_db)}
    coords = {d: outcome.coords[d] for d in grid if d in outcome.coords}
    return xr.DataArray(
        counts.reshape(sizes), dims=grid, coords=coords, name="responses", attrs=attrs
    )


def _count_block(
    kind: np.ndarray, period: np.ndarray, gamma: np.ndarray, se: np.ndarray, tol_db: float
) -> np.ndarray:
    """Connected components of the "same response" graph of each row (grid point), counting
    only the rows' counted computations (``kind >= 0``)."""
    g, m = kind.shape
    valid = kind >= 0
    ki, kj = kind[:, :, None], kind[:, None, :]
    same = (ki == kj) & valid[:, :, None] & valid[:, None, :]
    pi, pj = period[:, :, None], period[:, None, :]
    same_period = (pi == pj) | (np.isnan(pi) & np.isnan(pj))
    gi, gj = gamma[:, :, None], gamma[:, None, :]
    both_nan = np.isnan(gi) & np.isnan(gj)
    with np.errstate(invalid="ignore"):
        diff = np.abs(gi - gj)
        combined = IRREGULAR_SE * np.sqrt(se[:, :, None] ** 2 + se[:, None, :] ** 2)
    irregular = ki == COUNTED.index("irregular")
    close_periodic = both_nan | (diff <= tol_db)
    close_irregular = both_nan | np.where(np.isfinite(combined), diff < combined, diff <= tol_db)
    same &= np.where(irregular, close_irregular, close_periodic & same_period)
    # Imported here: only studies with several computations per grid point need them, and
    # without scipy.sparse the `impactcell run` command's imports took 2.0 s instead of 2.6–3.0.
    from scipy.sparse import coo_matrix
    from scipy.sparse.csgraph import connected_components

    rows, i, j = np.nonzero(same)
    n = g * m
    graph = coo_matrix(
        (np.ones(rows.size, dtype=np.int8), (rows * m + i, rows * m + j)), shape=(n, n)
    )
    _, labels = connected_components(graph, directed=False)
    labels = labels.reshape(g, m)
    found = np.unique(labels[valid])  # components of counted nodes (never across rows)
    first = np.zeros(labels.max() + 1 if labels.size else 0, dtype=np.int64)
    first[labels.ravel()] = np.repeat(np.arange(g), m)
    return np.bincount(first[found], minlength=g)
