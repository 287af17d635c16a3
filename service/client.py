"""A small Python client of the impactcell service (httpx, xarray and numpy; nothing else).

>>> from service.client import Client
>>> c = Client("http://127.0.0.1:8000", token=None)
>>> rec = c.submit("studies/quick.yaml")
>>> c.wait(rec["id"])
>>> ds = c.dataset(rec["id"])
>>> gaps = c.bandgap_map(rec["id"], x="gamma_r", y="gap", theta=0.3)
"""

from __future__ import annotations

import json
import os
import sys
import time
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import xarray as xr

__all__ = [
    "Client",
    "ClientError",
    "Conflict",
    "InvalidRequest",
    "NotFound",
    "PayloadTooLarge",
    "ServerError",
    "StudyFailed",
    "Unauthorized",
]


class ClientError(Exception):
    """An error answer of the service; ``status`` and the server's ``message``."""

    def __init__(self, status: int, message: str, problems: list[dict] | None = None) -> None:
        super().__init__(f"HTTP {status}: {message}")
        self.status = status
        self.message = message
        self.problems = problems or []


class InvalidRequest(ClientError):
    """400/415/422: the request (a study definition, a selection) is invalid."""


class Unauthorized(ClientError):
    """401: missing or wrong token."""


class NotFound(ClientError):
    """404: no such study or report."""


class Conflict(ClientError):
    """409: the study's state does not allow the action."""


class PayloadTooLarge(ClientError):
    """413: the request body is over the service's limit."""


class ServerError(ClientError):
    """5xx: the service failed."""


class StudyFailed(Exception):
    """``wait`` saw the study end ``failed`` or ``cancelled``."""

    def __init__(self, record: Mapping[str, Any]) -> None:
        super().__init__(
            f"study {record['id']} ended {record['status']}: {record.get('error') or ''}".strip()
        )
        self.record = dict(record)


_BY_STATUS: dict[int, type[ClientError]] = {
    400: InvalidRequest,
    401: Unauthorized,
    404: NotFound,
    409: Conflict,
    413: PayloadTooLarge,
    415: InvalidRequest,
    422: InvalidRequest,
}


class Client:
    """Talk to an impactcell service.

    Parameters
    ----------
    url : str
        Base URL, e.g. ``http://127.0.0.1:8000``.
    token : str, optional
        Bearer token (default: ``IMPACTCELL_API_TOKEN`` from the environment).
    transport : httpx.BaseTransport, optional
        For tests (e.g. an in-process app); default: real HTTP.
    timeout : float
        Seconds per request.
    """

    def __init__(
        self,
        url: str,
        token: str | None = None,
        *,
        transport: httpx.BaseTransport | None = None,
        timeout: float = 60.0,
    ) -> None:
        # The client may not import the service (httpx, xarray, numpy and the standard library
        # only), so it reads this one variable itself instead of through service Settings.
        token = token if token is not None else os.environ.get("IMPACTCELL_API_TOKEN") or None
        headers = {"Authorization": f"Bearer {token}"} if token else {}
        self._http = httpx.Client(
            base_url=url.rstrip("/"), headers=headers, transport=transport, timeout=timeout
        )

    def close(self) -> None:
        """Close the connection pool."""
        self._http.close()

    def __enter__(self) -> Client:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ------------------------------------------------------------------ plumbing

    def _request(self, method: str, path: str, **kwargs: Any) -> httpx.Response:
        r = self._http.request(method, path, **kwargs)
        if r.status_code >= 400:
            try:
                body = r.json()
                message = str(body.get("detail", r.text))
                problems = body.get("problems")
            except (ValueError, AttributeError):
                message, problems = r.text or r.reason_phrase, None
            fallback = ServerError if r.status_code >= 500 else ClientError
            cls = _BY_STATUS.get(r.status_code, fallback)
            raise cls(r.status_code, message, problems)
        return r

    # ------------------------------------------------------------------ studies

    def submit(self, definition: Mapping[str, Any] | str | os.PathLike[str]) -> dict[str, Any]:
        """Submit a study (a mapping, or a path to a YAML/JSON file); returns its record.

        Submitting an identical definition again returns the existing study.
        """
        if isinstance(definition, Mapping):
            r = self._request("POST", "/studies", json=dict(definition))
        else:
            p = Path(definition)
            text = p.read_text(encoding="utf-8")
            kind = "application/json" if p.suffix.lower() == ".json" else "application/yaml"
            r = self._request(
                "POST", "/studies", content=text.encode("utf-8"), headers={"Content-Type": kind}
            )
        return r.json()

    def get(self, study_id: str) -> dict[str, Any]:
        """The study's record (status, progress, timings, failures)."""
        return self._request("GET", f"/studies/{study_id}").json()

    def list(
        self, status: str | None = None, name: str | None = None, limit: int = 50, offset: int = 0
    ) -> list[dict[str, Any]]:
        """Studies, newest first."""
        params: dict[str, Any] = {"limit": limit, "offset": offset}
        if status:
            params["status"] = status
        if name:
            params["name"] = name
        return self._request("GET", "/studies", params=params).json()["items"]

    def cancel(self, study_id: str) -> dict[str, Any]:
        """Cancel a queued or running study (finished chunks are kept)."""
        return self._request("DELETE", f"/studies/{study_id}").json()

    def resume(self, study_id: str) -> dict[str, Any]:
        """Queue a cancelled or failed study again."""
        return self._request("POST", f"/studies/{study_id}/resume").json()

    def wait(
        self,
        study_id: str,
        progress: bool | Callable[[Mapping[str, Any]], None] = True,
        *,
        timeout: float | None = None,
        poll: float = 0.5,
    ) -> dict[str, Any]:
        """Poll until the study is finished; raises :class:`StudyFailed` if it fails/cancels.

        ``progress``: ``True`` shows a progress line on stderr; a callable is called with every
        record polled instead (e.g. to feed a progress bar of one's own).
        """
        t0 = time.monotonic()
        bar = _ProgressLine() if progress is True else None
        show = bar or progress or None
        try:
            while True:
                rec = self.get(study_id)
                if show:
                    show(rec)
                if rec["status"] == "finished":
                    return rec
                if rec["status"] in ("failed", "cancelled"):
                    raise StudyFailed(rec)
                if timeout is not None and time.monotonic() - t0 > timeout:
                    raise TimeoutError(
                        f"study {study_id} still {rec['status']} after {timeout:g} s "
                        f"({rec['points_done']}/{rec['points_total']} points)"
                    )
                time.sleep(poll)
        finally:
            if bar is not None:
                bar.close()

    # ------------------------------------------------------------------ results

    def dataset(self, study_id: str) -> xr.Dataset:
        """The results as an in-memory ``xarray.Dataset`` (partial while the study runs)."""
        r = self._request("GET", f"/studies/{study_id}/dataset")
        return _open_netcdf_bytes(r.content)

    def data(self, study_id: str, variable: str = "transmittance_db", nearest: bool = False,
             **sel: float) -> xr.DataArray:  # fmt: skip
        """A slice of one variable, selected by coordinate values."""
        params = {"variable": variable, "nearest": str(nearest).lower(), **_params(sel)}
        out = self._request("GET", f"/studies/{study_id}/data", params=params).json()
        coords = {k: np.asarray(v) for k, v in out["coords"].items()}
        values = np.asarray(_none_to_nan(out["values"]), dtype=float)
        da = xr.DataArray(values, dims=out["dims"], coords={d: coords[d] for d in out["dims"]},
                          name=out["variable"])  # fmt: skip
        da.attrs.update(units=out.get("units", ""), long_name=out.get("long_name", ""))
        return da

    def bandgap_map(
        self,
        study_id: str,
        x: str = "gamma_r",
        y: str | None = None,
        threshold_db: float = 0.0,
        nearest: bool = False,
        **sel: float,
    ) -> xr.Dataset:
        """The bandgap map: Γ over x × y, ``attenuating`` (Γ < threshold) and band edges."""
        params: dict[str, Any] = {"x": x, "threshold_db": threshold_db,
                                  "nearest": str(nearest).lower(), **_params(sel)}  # fmt: skip
        if y is not None:
            params["y"] = y
        out = self._request("GET", f"/studies/{study_id}/bandgap", params=params).json()
        return _bandgap_dataset(out)

    def plot(self, study_id: str, kind: str = "bandgap", **params: Any) -> bytes:
        """A PNG figure: ``transmittance``, ``bandgap`` or ``effective-mass``."""
        return self._request(
            "GET", f"/studies/{study_id}/plots/{kind}.png", params=_params(params)
        ).content

    def timeseries(self, study_id: str, periods: int = 5, nearest: bool = False,
                   **point: float) -> dict[str, Any]:  # fmt: skip
        """Recompute one point with time histories (JSON: ``series`` of lists, ``result``)."""
        params = {"periods": periods, "nearest": str(nearest).lower(), **_params(point)}
        return self._request("GET", f"/studies/{study_id}/timeseries", params=params).json()

    def health(self) -> dict[str, Any]:
        """``GET /health``."""
        return self._request("GET", "/health").json()

    def regressions(self) -> list[dict[str, Any]]:
        """Nightly regression runs, newest first."""
        return self._request("GET", "/regressions").json()["items"]

    def regression(self, reg_id: int) -> dict[str, Any]:
        """One nightly regression run, with its report once it has finished."""
        return self._request("GET", f"/regressions/{int(reg_id)}").json()

    def run_nightly(self) -> dict[str, Any]:
        """Start the nightly suite on the service, through its own job queue; returns the run's
        record (``regression(id)`` has the report once ``finished_at`` is set).

        Raises :class:`Conflict` while a run is in progress.
        """
        return self._request("POST", "/regressions").json()


def _params(sel: Mapping[str, Any]) -> dict[str, str]:
    return {k: repr(float(v)) if isinstance(v, float) else str(v) for k, v in sel.items()}


# The service's NaN-safe JSON helpers live in service.studies.dataset; the client may not import
# service modules, so it keeps this tiny inverse (JSON null back to NaN) of its own.
def _none_to_nan(values: Any) -> Any:
    if isinstance(values, list):
        return [_none_to_nan(v) for v in values]
    return np.nan if values is None else values


def _open_netcdf_bytes(content: bytes) -> xr.Dataset:
    import tempfile

    # netCDF4 reads from a path; the file is loaded fully and removed.
    with tempfile.NamedTemporaryFile(suffix=".nc", delete=False) as fh:
        fh.write(content)
        name = fh.name
    try:
        with xr.open_dataset(name, engine="netcdf4") as ds:
            return ds.load()
    finally:
        os.unlink(name)


def _bandgap_dataset(out: Mapping[str, Any]) -> xr.Dataset:
    x, y = out["x"], out.get("y")
    coords = {x: np.asarray(out["coords"][x], dtype=float)}
    dims: tuple[str, ...] = (x,)
    if y:
        coords[y] = np.asarray(out["coords"][y], dtype=float)
        dims = (y, x)
    gamma = np.asarray(_none_to_nan(out["transmittance_db"]), dtype=float)
    mask = np.asarray(out["attenuating"], dtype=bool)
    ds = xr.Dataset(
        {"transmittance_db": (dims, gamma, {"units": "dB"}), "attenuating": (dims, mask)},
        coords=coords,
        attrs={
            "threshold_db": out["threshold_db"],
            "x": x,
            "y": y or "",
            "edges": json.dumps(out["edges"]),
        },  # fmt: skip
    )
    return ds


class _ProgressLine:
    """A one-line progress display on stderr (the standard library only: no tqdm here)."""

    def __init__(self) -> None:
        self.drawn = False

    def __call__(self, rec: Mapping[str, Any]) -> None:
        done, total = rec["points_done"], rec["points_total"]
        pct = 100.0 * done / total if total else 100.0
        sys.stderr.write(f"\r{rec['name']}: {pct:5.1f}% {done:,}/{total:,} pt [{rec['status']}]")
        sys.stderr.flush()
        self.drawn = True

    def close(self) -> None:
        if self.drawn:
            sys.stderr.write("\n")
            sys.stderr.flush()
