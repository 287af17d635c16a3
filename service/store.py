"""The results store: every file path, chunk files, collation to xarray, NetCDF I/O.

Layout under the data root (``--out``, ``IMPACTCELL_DATA_DIR`` or ``./data``)::

    studies/<id>/study.json            canonical definition (written once)
    studies/<id>/chunks/<start>-<stop>.npz   one finished chunk of points
    studies/<id>/results.nc            the collated dataset (NetCDF4, zlib)

Ids are content hashes (:attr:`service.study.Study.id`), never user-chosen names. Every file is
written to a temporary name in the same folder, flushed, and renamed into place, so a crash
(even SIGKILL) never leaves a file that looks complete but is not.

How a point ended is ``outcome``: a CF flag variable (int8, ``flag_values`` 0…4 and
``flag_meanings`` "linear periodic irregular unsettled failed", the order of
``worker.solvers.settings.OUTCOMES``), never missing. Records carry it as a string, chunk files
and datasets as its flag value; :func:`outcome_names` reads it back as strings.

Missing values: a failed point has ``failed = 1``, ``outcome = failed``, a ``reason``, and every
measured variable missing. Some values are missing by nature at points that did not fail:
``transmittance_db_se`` (only irregular and unsettled points have one), ``floquet_multiplier``
(only linear and periodic points), ``theta_eff_slope`` (where the phase portrait has no slope).
Floats are NaN in memory and the netCDF ``_FillValue`` on disk (no NaN is written); integer
variables that can be missing (``response_period``, ``steady_period``) are stored as int32 with
``_FillValue = -1`` and read back by xarray as float with NaN.
"""

from __future__ import annotations

import datetime as _dt
import json
import os
import re
import subprocess
import tempfile
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from importlib import metadata
from pathlib import Path
from typing import Any

import numpy as np
import xarray as xr

from service.study import Study
from worker.simulate import SOLVER_VERSION
from worker.solvers.settings import OUTCOMES

__all__ = [
    "CHUNK_FIELDS",
    "FILL_FLOAT",
    "OUTCOMES",
    "PENDING",
    "StudyStore",
    "VARIABLES",
    "atomic_write",
    "outcome_attrs",
    "outcome_codes",
    "outcome_counts",
    "outcome_names",
    "package_version",
    "data_root",
    "open_results",
    "results_from_records",
]

FILL_FLOAT = 9.969209968386869e36  # netCDF's default double fill (NC_FILL_DOUBLE)
FILL_INT = -1
PENDING = "pending: not computed yet"  # reason of points a partial dataset does not have yet
_STUDY_ID = re.compile(r"^[0-9a-f]{8,64}$")
_CHUNK = re.compile(r"^(\d+)-(\d+)\.npz$")


@dataclass(frozen=True)
class _Var:
    group: str  # outputs group ("" = always stored)
    kind: str  # float | int | maskint | bool | str | flag (int8 CF flag of OUTCOMES)
    units: str
    long_name: str
    mask: bool = True  # missing where the point failed


# Result variables, in the order they appear in the dataset.
VARIABLES: dict[str, _Var] = {
    "transmittance_db": _Var(
        "transmittance", "float", "dB",
        "transmittance Gamma = 20 log10(A_s / (theta gamma_s)) (Eq. 32); the mean over "
        "measurement windows for irregular and unsettled points",
    ),
    "transmittance_db_se": _Var(
        "transmittance", "float", "dB",
        "standard error of the transmittance of an irregular or unsettled point (batch means "
        "over measurement windows); missing for linear and periodic points",
    ),
    "amplitude": _Var(
        "transmittance", "float", "1",
        "displacement amplitude A_s of the outer mass in units of B = U_g / (theta gamma_s)",
    ),
    "theta_eff": _Var(
        "effective_mass", "float", "1",
        "effective mass ratio from first harmonics at gamma_r (Eq. 35)",
    ),
    "theta_eff_slope": _Var(
        "effective_mass", "float", "1",
        "effective mass ratio from the least-squares slope of the velocity phase portrait, "
        "(kappa - theta <s_b_dot s_dot> / <s_dot^2>) / (1 + theta); missing if undefined",
    ),
    "outcome": _Var(
        "response", "flag", "1",
        "how the point ended: linear (closed-form steady state, impact-free), periodic "
        "(confirmed orbit with impacts), irregular (converged window statistics), unsettled "
        "(period budget ran out first) or failed",
        mask=False,
    ),
    "response_period": _Var(
        "response", "maskint", "1",
        "response period in excitation periods (1 = linear, p = periodic orbit, "
        "0 = irregular or unsettled)",
    ),
    "impacts_per_period": _Var("response", "float", "1", "impacts per excitation period at stop"),
    "floquet_multiplier": _Var(
        "response", "float", "1",
        "estimate of the modulus of the dominant Floquet multiplier of the steady response "
        "(linear and periodic points; missing otherwise)",
    ),
    "periods": _Var("response", "int", "1", "excitation periods simulated", mask=False),
    "steps": _Var("response", "int", "1", "time steps taken", mask=False),
    "peak_impulse": _Var("contact", "float", "1", "largest contact impulse (non-dimensional)"),
    "contact_steps": _Var(
        "contact", "int", "1", "time steps that needed a contact solve", mask=False
    ),
    "coarse_steps": _Var(
        "contact", "int", "1", "free-flight coarse steps taken whole (exponential)", mask=False
    ),
    "steady_period": _Var(
        "contact", "maskint", "1", "period index at which the steady state was detected"
    ),
    "failed": _Var("", "bool", "1", "point failed (see reason); its results are missing",
                   mask=False),
    "reason": _Var("", "str", "1", "why the point failed or is unsettled, or a caveat of an "
                   "irregular point; empty otherwise", mask=False),
    "wall_s": _Var("", "float", "s", "wall-clock time of the point's kernel", mask=False),
}  # fmt: skip


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


# Fields kept in chunk files (everything simulate_chunk reports that a dataset may hold).
CHUNK_FIELDS = tuple(VARIABLES)

_AXIS_ATTRS: dict[str, tuple[str, str]] = {
    "gamma_r": ("1", "excitation frequency gamma_r = Omega / omega_b"),
    "gap": ("1", "clearance to both stops g1 = g2, in units of B"),
    "g1": ("1", "clearance to stop 1, in units of B"),
    "g2": ("1", "clearance to stop 2, in units of B"),
    "theta": ("1", "mass ratio theta = rho A l / m_o"),
    "sigma": ("1", "beam stiffness parameter sigma = EI / (rho A l^4 omega_b^2)"),
    "gamma_s": ("1", "inverse mass frequency gamma_s = omega_b / omega_m"),
    "xi": ("1", "damping ratio xi"),
    "frequency_hz": ("Hz", "excitation frequency"),
    "length_m": ("m", "beam free length"),
    "width_m": ("m", "beam width"),
    "thickness_m": ("m", "beam thickness"),
    "density_kg_m3": ("kg m-3", "beam density"),
    "youngs_modulus_pa": ("Pa", "beam Young's modulus"),
    "outer_mass_kg": ("kg", "outer mass"),
    "spring_n_m": ("N m-1", "spring stiffness"),
    "damping_ratio": ("1", "damping ratio of the outer dashpot"),
    "gap_m": ("m", "clearance to both stops"),
    "gap1_m": ("m", "clearance to stop 1"),
    "gap2_m": ("m", "clearance to stop 2"),
    "base_amplitude_m": ("m", "base displacement amplitude U_g"),
    "base_acceleration_m_s2": ("m s-2", "base acceleration amplitude"),
    "stop": ("1", "stop index (1 or 2)"),
}
_DERIVED = ("gamma_r", "theta", "sigma", "gamma_s", "xi", "g1", "g2")


def data_root(out: str | os.PathLike[str] | None = None) -> Path:
    """The data root: ``out``, else ``IMPACTCELL_DATA_DIR``, else ``./data``."""
    if out is not None:
        return Path(out)
    return Path(os.environ.get("IMPACTCELL_DATA_DIR", "data"))


def atomic_write(path: Path, write: Callable[[Path], None]) -> None:
    """Call ``write(tmp)`` on a temporary file next to ``path``, fsync it, rename into place."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, name = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    os.close(fd)
    tmp = Path(name)
    try:
        write(tmp)
        with open(tmp, "rb") as fh:
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    try:  # make the rename itself durable
        dfd = os.open(path.parent, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(dfd)
    except OSError:
        pass
    finally:
        os.close(dfd)


# --------------------------------------------------------------------------- records -> arrays


def _columns(records: Sequence[Mapping[str, Any]]) -> dict[str, np.ndarray]:
    """Per-field arrays of result records; ``None`` becomes NaN (floats) or -1 (ints), the
    ``outcome`` string its flag value."""
    n = len(records)
    cols: dict[str, np.ndarray] = {}
    for name, var in VARIABLES.items():
        if name == "impacts_per_period":
            arr = np.full((n, 2), np.nan)
            for i, r in enumerate(records):
                v = r.get(name)
                if v is not None:
                    arr[i] = v
        elif var.kind == "float":
            arr = np.array(
                [np.nan if r.get(name) is None else float(r[name]) for r in records],
                dtype=np.float64,
            )
        elif var.kind in ("int", "maskint"):
            arr = np.array(
                [FILL_INT if r.get(name) is None else int(r[name]) for r in records],
                dtype=np.int64,
            )
        elif var.kind == "bool":
            arr = np.array([bool(r.get(name)) for r in records], dtype=bool)
        elif var.kind == "flag":
            arr = outcome_codes(r.get(name) for r in records)
        else:
            arr = np.array([str(r.get(name) or "") for r in records], dtype=np.str_)
            if arr.dtype.itemsize == 0:
                arr = arr.astype("<U1")
        cols[name] = arr
    return cols


# --------------------------------------------------------------------------- the store


class StudyStore:
    """Files of one study under a data root."""

    def __init__(self, root: str | os.PathLike[str] | None, study: Study) -> None:
        self.study = study
        self.id = study.id
        if not _STUDY_ID.match(self.id):
            raise ValueError(f"study id must be a hex digest, got {self.id!r}")
        self.folder = data_root(root) / "studies" / self.id
        self.chunk_dir = self.folder / "chunks"

    @property
    def results_path(self) -> Path:
        """Where the collated NetCDF file goes."""
        return self.folder / "results.nc"

    @property
    def definition_path(self) -> Path:
        """Where the canonical definition goes."""
        return self.folder / "study.json"

    def prepare(self) -> None:
        """Create the folder and record the definition (refusing a hash collision)."""
        self.chunk_dir.mkdir(parents=True, exist_ok=True)
        text = self.study.canonical_json()
        if self.definition_path.exists():
            on_disk = json.loads(self.definition_path.read_text(encoding="utf-8"))
            if on_disk.get("definition") != self.study.canonical():
                raise ValueError(
                    f"study folder {self.folder} holds a different definition; remove it"
                )
            return
        payload = json.dumps(
            {"id": self.id, "solver_version": SOLVER_VERSION, "definition": json.loads(text)},
            indent=1,
            sort_keys=True,
        )
        atomic_write(self.definition_path, lambda p: p.write_text(payload, encoding="utf-8"))
        for stale in self.chunk_dir.glob(".*.tmp"):  # left by a crash mid-write
            stale.unlink(missing_ok=True)

    # ---------------------------------------------------------------- chunks

    def write_chunk(
        self, start: int, stop: int, records: Sequence[Mapping[str, Any]], *, retry: bool = False
    ) -> Path:
        """Write one finished chunk atomically; ``retry`` marks results to recompute on resume."""
        if len(records) != stop - start:
            raise ValueError(
                f"chunk {start}-{stop} needs {stop - start} records, got {len(records)}"
            )
        cols = _columns(records)
        path = self.chunk_dir / f"{start}-{stop}.npz"

        def write(tmp: Path) -> None:
            with open(tmp, "wb") as fh:
                np.savez(fh, _start=start, _stop=stop, _retry=retry, **cols)

        atomic_write(path, write)
        return path

    def chunks(self) -> list[tuple[int, int, Path]]:
        """Finished chunk files as (start, stop, path), by start."""
        if not self.chunk_dir.is_dir():
            return []
        out = []
        for p in self.chunk_dir.iterdir():
            m = _CHUNK.match(p.name)
            if m:
                out.append((int(m.group(1)), int(m.group(2)), p))
        return sorted(out)

    def _load_chunk(self, path: Path) -> dict[str, np.ndarray] | None:
        try:
            with np.load(path, allow_pickle=False) as z:
                return {k: z[k] for k in z.files}
        except (OSError, ValueError, KeyError, EOFError):
            return None

    def done_mask(self) -> np.ndarray:
        """Boolean mask of points whose results are stored (and need no retry).

        Chunk files that cannot be read, or that hold retry-later failures, are removed so that
        their points are computed again.
        """
        done = np.zeros(self.study.size, dtype=bool)
        for start, stop, path in self.chunks():
            ok = 0 <= start < stop <= self.study.size
            if ok:
                data = self._load_chunk(path)
                ok = data is not None and not bool(data["_retry"])
            if not ok:
                path.unlink(missing_ok=True)
                continue
            done[start:stop] = True
        return done

    def has_retry_chunks(self) -> bool:
        """Whether some stored chunk failed as a task and should be computed again."""
        for _, _, path in self.chunks():
            data = self._load_chunk(path)
            if data is None or bool(data["_retry"]):
                return True
        return False

    def missing_ranges(self) -> list[tuple[int, int]]:
        """Maximal runs of points with no stored result, as (start, stop)."""
        done = self.done_mask()
        edges = np.flatnonzero(np.diff(np.r_[1, done.view(np.int8), 1]))
        return [(int(a), int(b)) for a, b in zip(edges[::2], edges[1::2], strict=True)]

    def collect(self) -> dict[str, np.ndarray]:
        """Every point's stored results as flat arrays; raises if any point is missing."""
        cols, filled = self._gather(strict=True)
        if not filled.all():
            n = filled.size
            raise ValueError(f"{int((~filled).sum())} of {n} points have no results yet")
        return cols

    def collect_partial(self) -> tuple[dict[str, np.ndarray], np.ndarray]:
        """Results stored so far, and the mask of points that have them.

        Points without results are filled as failed with reason ``pending``. Chunk files that
        vanish while reading (a run finishing and tidying up) are treated as not there.
        """
        cols, filled = self._gather(strict=False)
        missing = int((~filled).sum())
        if missing:
            from worker.simulate import SolverSettings, failed_result

            rec = failed_result(SolverSettings(**self.study.solver.model_dump()), PENDING)
            fill = _columns([rec])
            for name, arr in fill.items():
                if name not in cols:
                    dtype = object if arr.dtype.kind == "U" else arr.dtype
                    cols[name] = np.empty((filled.size, *arr.shape[1:]), dtype=dtype)
                cols[name][~filled] = arr[0]
        return cols, filled

    def _gather(self, strict: bool) -> tuple[dict[str, np.ndarray], np.ndarray]:
        n = self.study.size
        filled = np.zeros(n, dtype=bool)
        cols: dict[str, np.ndarray] = {}
        for start, stop, path in self.chunks():
            data = self._load_chunk(path)
            if data is None and not strict:
                continue
            if data is None:
                raise ValueError(f"chunk file {path} cannot be read")
            if filled[start:stop].any():
                raise ValueError(f"chunk file {path} overlaps another chunk")
            for name in CHUNK_FIELDS:
                a = data[name]
                if name not in cols:
                    dtype = object if a.dtype.kind == "U" else a.dtype
                    cols[name] = np.empty((n, *a.shape[1:]), dtype=dtype)
                cols[name][start:stop] = a
            filled[start:stop] = True
        return cols, filled

    # ---------------------------------------------------------------- results

    def write_results(self, ds: xr.Dataset) -> Path:
        """Write the collated dataset atomically (NetCDF4, zlib)."""
        enc = encoding(ds)
        atomic_write(self.results_path, lambda p: ds.to_netcdf(p, engine="netcdf4", encoding=enc))
        return self.results_path

    def remove_chunks(self) -> None:
        """Delete the chunk files once the results file holds them."""
        for _, _, path in self.chunks():
            path.unlink(missing_ok=True)


# --------------------------------------------------------------------------- collation


def _git_commit() -> str:
    try:
        out = subprocess.run(
            ["git", "rev-parse", "HEAD"],
            cwd=Path(__file__).resolve().parent,
            capture_output=True,
            text=True,
            timeout=5,
            check=False,
        )
    except (OSError, subprocess.SubprocessError):
        return "unknown"
    text = out.stdout.strip()
    return text if out.returncode == 0 and re.fullmatch(r"[0-9a-f]{40}", text) else "unknown"


def package_version() -> str:
    """The installed impactcell version (``unknown`` when not installed)."""
    try:
        return metadata.version("impactcell")
    except metadata.PackageNotFoundError:
        return "unknown"


def _attrs(name: str) -> dict[str, str]:
    units, long_name = _AXIS_ATTRS[name]
    return {"units": units, "long_name": long_name}


def results_from_records(
    study: Study,
    cols: Mapping[str, np.ndarray],
    *,
    created: str | None = None,
    computed: np.ndarray | None = None,
) -> xr.Dataset:
    """Collate flat per-point arrays (C order over the study's axes) into a Dataset.

    ``computed`` (a flat mask) marks a partial dataset: it adds a ``pending`` variable and the
    global attributes ``partial = 1`` and ``points_done``.
    """
    dims_map = study.dims()
    dims = tuple(dims_map)
    shape = study.shape
    coords: dict[str, Any] = {k: (k, v, _attrs(k)) for k, v in dims_map.items()}
    for k, v in study.scalars().items():
        coords[k] = ((), v, _attrs(k))
    coords["stop"] = ("stop", np.array([1, 2], dtype=np.int8), _attrs("stop"))
    if study.is_physical:
        # Results carry the model's parameters too (γ_r next to Hz, and the rest).
        pts = list(study.iter_points())
        for k in _DERIVED:
            v = np.array([p[k] for p in pts], dtype=np.float64)
            attrs = dict(_attrs(k))
            attrs["long_name"] += " (derived from the physical cell, docs/model.md section 8)"
            if k in coords:
                continue
            arr, kept = v.reshape(shape), list(dims)
            for ax in reversed(range(len(dims))):  # keep only the dims it varies along
                if np.all(arr == arr.take([0], axis=ax)):
                    arr = arr.take(0, axis=ax)
                    kept.pop(ax)
            coords[k] = (tuple(kept), arr, attrs) if kept else ((), float(arr), attrs)

    failed = np.asarray(cols["failed"], dtype=bool)
    groups = {g for g, on in study.outputs.model_dump().items() if on} | {""}
    data_vars: dict[str, Any] = {}
    for name, var in VARIABLES.items():
        if var.group not in groups:
            continue
        a = np.asarray(cols[name])
        if var.kind in ("float", "maskint"):
            a = a.astype(np.float64)
            if var.kind == "maskint":
                a[a == FILL_INT] = np.nan
            if var.mask:
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
        if name == "impacts_per_period":
            data_vars[name] = ((*dims, "stop"), a.reshape(*shape, 2), attrs)
        else:
            data_vars[name] = (dims, a.reshape(shape), attrs)
    settings = study.solver.settings()
    attrs = {
        "Conventions": "CF-1.8",
        "title": f"impactcell study {study.name}",
        "study_name": study.name,
        "study_id": study.id,
        "study": study.canonical_json(),
        "impactcell_version": package_version(),
        "solver_version": SOLVER_VERSION,
        "solver_settings": json.dumps(_settings_dict(settings), sort_keys=True),
        "git_commit": _git_commit(),
        "created": created or _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"),
        "source": "impactcell simulation of an impacting beam-in-mass metamaterial cell",
        "comment": (
            "failed = 1 marks a point that could not be computed; its measured variables are "
            "missing (_FillValue) and reason says why"
        ),
    }
    if computed is not None:
        data_vars["pending"] = (
            dims,
            ~np.asarray(computed, dtype=bool).reshape(shape),
            {"units": "1", "long_name": "point not computed yet (partial dataset)"},
        )
        attrs["partial"] = np.int8(1)
        attrs["points_done"] = int(np.sum(computed))
        attrs["comment"] += "; partial dataset: pending = 1 marks points not computed yet"
    return xr.Dataset(data_vars, coords=coords, attrs=attrs)


def _settings_dict(settings: Any) -> dict[str, Any]:
    from dataclasses import asdict

    return asdict(settings)


def encoding(ds: xr.Dataset) -> dict[str, dict[str, Any]]:
    """NetCDF encoding: zlib everywhere it applies, fill values for missing, no NaN on disk."""
    enc: dict[str, dict[str, Any]] = {}
    for name in ds.data_vars:
        var = VARIABLES.get(str(name))
        dt = ds[name].dtype
        kind = var.kind if var else {"O": "str", "b": "bool"}.get(dt.kind, "float")
        if kind == "str":
            enc[str(name)] = {}  # variable-length strings take no compression filter
        elif kind == "maskint":
            enc[str(name)] = {"dtype": "int32", "_FillValue": FILL_INT, "zlib": True}
        elif kind == "float":
            enc[str(name)] = {"_FillValue": FILL_FLOAT, "zlib": True}
        elif kind == "flag":
            enc[str(name)] = {"dtype": "int8", "_FillValue": None, "zlib": True}  # never missing
        else:
            enc[str(name)] = {"zlib": True}
    for name in ds.coords:
        if ds[name].dtype.kind == "f":
            enc[str(name)] = {"_FillValue": None}  # coordinates are never missing
    return enc


def open_results(path: str | os.PathLike[str]) -> xr.Dataset:
    """Open a results file fully into memory (the file is closed afterwards)."""
    p = Path(path)
    if not p.is_file():
        raise ValueError(f"no such results file: {p}")
    try:
        with xr.open_dataset(p, engine="netcdf4") as ds:
            return ds.load()
    except OSError as exc:
        raise ValueError(f"{p} is not a readable NetCDF file: {exc}") from None


def summarize(ds: xr.Dataset) -> dict[str, Any]:
    """Counts of a results dataset: points, failed, and points by outcome when it is stored."""
    failed = ds["failed"].values.astype(bool)
    out: dict[str, Any] = {"points": int(failed.size), "failed": int(failed.sum())}
    if "outcome" in ds:
        out.update(outcome_counts(outcome_names(ds["outcome"])))
    return out


def iter_chunk_ranges(ranges: Iterable[tuple[int, int]], size: int) -> list[tuple[int, int]]:
    """Split (start, stop) runs into pieces of at most ``size`` points."""
    if size < 1:
        raise ValueError(f"chunk size must be >= 1, got {size}")
    out = []
    for a, b in ranges:
        for s in range(a, b, size):
            out.append((s, min(s + size, b)))
    return out
