"""A small Python client of the impactcell service (httpx, xarray and numpy; nothing else).

>>> from service.client import Client
>>> c = Client("http://127.0.0.1:8000", token=None)
>>> rec = c.submit("studies/quick.yaml")
>>> c.wait(rec["id"])
>>> ds = c.dataset(rec["id"])
>>> gaps = c.bandgap_map(rec["id"], x="gamma_r", y="gap", theta=0.3)
>>> loops = c.hysteresis(rec["id"])  # sweep or multi-start studies: branches, jumps

Contract with the service: ``cancel`` is ``POST /studies/{id}/cancel`` (finished chunks kept),
``delete`` is ``DELETE /studies/{id}`` (the study and its files removed), ``submit(...,
resume=True)`` asks the service to resume an identical cancelled or failed study.
"""

from __future__ import annotations

import json
import math
import os
import sys
import tempfile
import time
from collections.abc import Callable, Iterable, Mapping
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
    "NotAService",
    "NotFound",
    "PayloadTooLarge",
    "ServerError",
    "StudyFailed",
    "StudyPage",
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


class NotAService(ClientError):
    """The answer is not one of an impactcell service (an HTML page, another server's answer):
    the URL is not the service's, or a proxy in front of it answered."""


class StudyFailed(Exception):
    """``wait`` saw the study end ``failed`` or ``cancelled``; the message says how to resume."""

    def __init__(self, record: Mapping[str, Any]) -> None:
        sid, status = record["id"], record["status"]
        text = f"study {sid} ended {status}"
        if record.get("error"):
            text += f": {record['error']}"
        text += (
            f"; its finished points are kept: resume it with Client.resume({sid!r}) or "
            "Client.submit(definition, resume=True)"
        )
        super().__init__(text)
        self.record = dict(record)


class StudyPage(list):  # a list, so code written when list() returned one keeps working
    """A page of ``Client.list``: a list of study records (as before) that also carries
    ``total`` (studies matching, over all pages), ``limit`` and ``offset``."""

    def __init__(self, items: Iterable[dict[str, Any]], total: int, limit: int, offset: int):
        super().__init__(items)
        self.total = total
        self.limit = limit
        self.offset = offset


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
        if method != "GET":
            # The service takes a state change only with a JSON or YAML body type (a page of
            # another site cannot send one without asking first), also when there is no body.
            headers = {"Content-Type": "application/json", **(kwargs.pop("headers", None) or {})}
            kwargs["headers"] = headers
        r = self._http.request(method, path, **kwargs)
        _raise_for(r)
        _check_not_a_page(r)
        return r

    def _json(self, method: str, path: str, **kwargs: Any) -> Any:
        """The JSON body of an answer; :class:`NotAService` when it is none (another server)."""
        r = self._request(method, path, **kwargs)
        if _content_type(r) == "application/json":
            try:
                return r.json()
            except ValueError:
                pass
        raise _not_a_service(r)

    def _download(
        self,
        path: str,
        params: Mapping[str, Any] | None = None,
        headers: dict[str, str] | None = None,
    ) -> xr.Dataset:
        """Stream a NetCDF answer to a temporary file (never whole in memory), load it;
        ``headers``, if given, receives the response's headers."""
        fd, name = tempfile.mkstemp(suffix=".nc", prefix="impactcell-client-")
        try:
            with os.fdopen(fd, "wb") as fh, self._http.stream("GET", path, params=params) as r:
                if r.status_code >= 400:
                    r.read()
                    _raise_for(r)
                _check_not_a_page(r)
                if headers is not None:
                    headers.update(r.headers)
                for block in r.iter_bytes(1 << 20):
                    fh.write(block)
            with xr.open_dataset(name, engine="netcdf4") as ds:
                return ds.load()
        finally:
            os.unlink(name)

    # ------------------------------------------------------------------ studies

    def submit(
        self, definition: Mapping[str, Any] | str | os.PathLike[str], resume: bool = False
    ) -> dict[str, Any]:
        """Submit a study (a mapping, or a path to a YAML/JSON file); returns its record.

        Submitting an identical definition again returns the existing study. With ``resume``
        (``POST /studies?resume=true``), an identical study that was cancelled or failed is
        queued again to continue from its finished chunks instead of being returned as it is.
        A NaN or infinite number in a mapping or JSON file raises :class:`InvalidRequest`
        naming its path (``grid.gamma_r.start``) before anything is sent.
        """
        params = {"resume": "true"} if resume else None
        if isinstance(definition, Mapping):
            _check_finite(definition)
            # allow_nan=False: what _check_finite let through is standard JSON
            body = json.dumps(dict(definition), allow_nan=False).encode("utf-8")
            kind = "application/json"
        else:
            p = Path(definition)
            text = p.read_text(encoding="utf-8")
            kind = "application/json" if p.suffix.lower() == ".json" else "application/yaml"
            if kind == "application/json":
                try:
                    parsed = json.loads(text)
                except ValueError:  # not JSON: the service says so, with its message
                    parsed = None
                _check_finite(parsed)
            body = text.encode("utf-8")
        return self._json(
            "POST", "/studies", content=body, headers={"Content-Type": kind}, params=params
        )

    def get(self, study_id: str) -> dict[str, Any]:
        """The study's record (status, progress, timings, failures)."""
        return self._json("GET", f"/studies/{study_id}")

    def list(
        self,
        status: str | None = None,
        name: str | None = None,
        limit: int = 50,
        offset: int = 0,
        full: bool = False,
    ) -> StudyPage:
        """Studies, newest first: a :class:`StudyPage` (a list of records, as before, with
        ``total``, ``limit`` and ``offset``); ``full`` includes each definition (else
        ``None``)."""
        params: dict[str, Any] = {"limit": limit, "offset": offset, "full": full}
        if status:
            params["status"] = status
        if name:
            params["name"] = name
        body = self._json("GET", "/studies", params=params)
        items = body["items"]
        return StudyPage(items, int(body.get("total", len(items))), int(body.get("limit", limit)),
                         int(body.get("offset", offset)))  # fmt: skip

    def cancel(self, study_id: str) -> dict[str, Any]:
        """Cancel a queued or running study (``POST /studies/{id}/cancel``): running work
        stops, finished chunks are kept; ``resume`` continues it."""
        return self._json("POST", f"/studies/{study_id}/cancel")

    def delete(self, study_id: str) -> None:
        """Remove a study and its files (``DELETE /studies/{id}``); it cannot be resumed."""
        self._request("DELETE", f"/studies/{study_id}")

    def resume(self, study_id: str) -> dict[str, Any]:
        """Queue a cancelled or failed study again."""
        return self._json("POST", f"/studies/{study_id}/resume")

    def wait(
        self,
        study_id: str,
        progress: bool | Callable[[Mapping[str, Any]], None] = True,
        *,
        timeout: float | None = None,
        poll: float = 0.5,
    ) -> dict[str, Any]:
        """Poll until the study is finished; raises :class:`StudyFailed` if it fails/cancels
        (a ``waiting`` study, paused by an outage, is waited for: it goes on by itself).

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
        """The results as an in-memory ``xarray.Dataset`` (partial while the study runs);
        the file is streamed to disk first, never held whole in memory twice."""
        return self._download(f"/studies/{study_id}/dataset")

    def data(self, study_id: str, variable: str = "transmittance_db", nearest: bool = False,
             **sel: float) -> xr.DataArray:  # fmt: skip
        """A slice of one variable, selected by coordinate values.

        Values keep their type: floats (NaN for missing), integers, booleans, strings
        (``variable="reason"``); ``outcome`` is its flag codes with ``flag_values`` and
        ``flag_meanings`` attributes. A slice over the service's limit (100,000 values) is
        an :class:`InvalidRequest` saying what to select.
        """
        params = {"variable": variable, "nearest": str(nearest).lower(), **_params(sel)}
        out = self._json("GET", f"/studies/{study_id}/data", params=params)
        coords = {k: np.asarray(v) for k, v in out["coords"].items()}
        values = _typed(out["values"], out.get("dtype", "float"))
        da = xr.DataArray(values, dims=out["dims"], coords={d: coords[d] for d in out["dims"]},
                          name=out["variable"])  # fmt: skip
        for k, v in out.get("scalars", {}).items():
            da = da.assign_coords({k: v})
        da.attrs.update(units=out.get("units", ""), long_name=out.get("long_name", ""))
        if "flag_meanings" in out:
            da.attrs.update(flag_values=np.asarray(out["flag_values"]),
                            flag_meanings=" ".join(out["flag_meanings"]))  # fmt: skip
        return da

    def data_csv(self, study_id: str, variable: str = "transmittance_db",
                 nearest: bool = False, **sel: float) -> str:  # fmt: skip
        """A slice as CSV text (long form: one row per value, a column per coordinate)."""
        params = {"variable": variable, "nearest": str(nearest).lower(), "format": "csv",
                  **_params(sel)}  # fmt: skip
        return self._request("GET", f"/studies/{study_id}/data", params=params).text

    def bandgap_map(
        self,
        study_id: str,
        x: str | None = None,
        y: str | None = None,
        threshold_db: float | None = None,
        nearest: bool = False,
        variable: str = "transmittance_db",
        **sel: float,
    ) -> xr.Dataset:
        """The bandgap map: ``variable`` over x × y, ``attenuating`` (below the threshold) and
        band edges.

        ``variable`` is ``transmittance_db`` (Γ), ``transmittance_linear_db`` (Γ_lin, the same
        cell without stops) or ``impact_effect_db`` (Γ − Γ_lin: bands where impacts add
        attenuation); ``threshold_db`` defaults to the service's (0 dB, 0 dB, −1 dB). ``x`` and
        ``y`` default as in the service (the frequency axis, then the first other varying axis
        with few values; other axes at their first value). The attributes hold the JSON's
        description: ``variable``, ``threshold_db``, ``x``, ``y``, ``edges`` and ``slice``
        (JSON text).
        """
        out = self.bandgap_json(study_id, x, y, threshold_db, nearest, variable, **sel)
        return _bandgap_dataset(out)

    def bandgap_json(
        self,
        study_id: str,
        x: str | None = None,
        y: str | None = None,
        threshold_db: float | None = None,
        nearest: bool = False,
        variable: str = "transmittance_db",
        **sel: float,
    ) -> dict[str, Any]:
        """The bandgap document as the service sends it (plain JSON data, ``bandgap.json``):
        it names its variable, axes (units, long names, values), threshold and the slice it
        was taken at, with the map and the band edges."""
        params = self._bandgap_params(x, y, threshold_db, nearest, variable, sel)
        return self._json("GET", f"/studies/{study_id}/bandgap", params=params)

    def bandgap_csv(
        self,
        study_id: str,
        x: str | None = None,
        y: str | None = None,
        threshold_db: float | None = None,
        nearest: bool = False,
        variable: str = "transmittance_db",
        **sel: float,
    ) -> str:
        """The band edges as CSV text, one row per band (``format=csv`` of ``/bandgap``)."""
        params = self._bandgap_params(x, y, threshold_db, nearest, variable, sel)
        params["format"] = "csv"
        return self._request("GET", f"/studies/{study_id}/bandgap", params=params).text

    @staticmethod
    def _bandgap_params(x: str | None, y: str | None, threshold_db: float | None,
                        nearest: bool, variable: str,
                        sel: Mapping[str, Any]) -> dict[str, Any]:  # fmt: skip
        params: dict[str, Any] = {"variable": variable, "nearest": str(nearest).lower(),
                                  **_params(sel)}  # fmt: skip
        if threshold_db is not None:
            params["threshold_db"] = threshold_db
        if x is not None:
            params["x"] = x
        if y is not None:
            params["y"] = y
        return params

    def hysteresis(
        self,
        study_id: str,
        x: str | None = None,
        variable: str = "transmittance_db",
        jump_db: float | None = None,
        tol_db: float | None = None,
        nearest: bool = False,
        **sel: Any,
    ) -> dict[str, Any]:
        """The hysteresis map of a sweep or multi-start study (``GET /studies/{id}/hysteresis``)
        as the service sends it: ``branches`` (``up``, ``down``, each initial state: label,
        values along ``axes.x``, outcomes, jumps), ``jumps`` (label, branch, from, to,
        size_db, kind: discontinuities only, docs/service.md), ``differing`` (intervals of x
        where the branches differ), ``responses``, ``slice`` and the thresholds with their
        meaning. ``x`` defaults to the swept axis;
        ``direction=``/``initial=`` keep only those branches; ``jump_db`` and ``tol_db``
        default to the service's (1 and 0.05 dB). A study without a sweep or several starts
        is an :class:`InvalidRequest`.
        """
        params = self._hysteresis_params(x, variable, jump_db, tol_db, nearest, sel)
        return self._json("GET", f"/studies/{study_id}/hysteresis", params=params)

    def hysteresis_csv(
        self,
        study_id: str,
        x: str | None = None,
        variable: str = "transmittance_db",
        jump_db: float | None = None,
        tol_db: float | None = None,
        nearest: bool = False,
        **sel: Any,
    ) -> str:
        """The hysteresis map as CSV text, one row per branch and x value (``format=csv``)."""
        params = self._hysteresis_params(x, variable, jump_db, tol_db, nearest, sel)
        params["format"] = "csv"
        return self._request("GET", f"/studies/{study_id}/hysteresis", params=params).text

    @staticmethod
    def _hysteresis_params(x: str | None, variable: str, jump_db: float | None,
                           tol_db: float | None, nearest: bool,
                           sel: Mapping[str, Any]) -> dict[str, Any]:  # fmt: skip
        params: dict[str, Any] = {"variable": variable, "nearest": str(nearest).lower(),
                                  **_params(sel)}  # fmt: skip
        for name, value in (("x", x), ("jump_db", jump_db), ("tol_db", tol_db)):
            if value is not None:
                params[name] = value
        return params

    def plot(self, study_id: str, kind: str = "bandgap", fmt: str = "png", **params: Any) -> bytes:
        """A figure, ``fmt`` ``png`` or ``svg``: ``transmittance``, ``bandgap``,
        ``effective-mass`` or ``hysteresis`` (sweep and multi-start studies: up and down
        curves, jumps, where they differ). Axes not given are chosen by the service (named in
        the title)."""
        if fmt not in ("png", "svg"):
            raise ValueError(f"fmt must be png or svg, got {fmt!r}")
        return self._request(
            "GET", f"/studies/{study_id}/plots/{kind}.{fmt}", params=_params(params)
        ).content

    def timeseries(self, study_id: str, periods: int = 5, nearest: bool = False,
                   **point: float) -> xr.Dataset:  # fmt: skip
        """Recompute one point with time histories: an ``xarray.Dataset`` over ``time`` (and
        ``event`` for the event log); attributes ``point`` and ``result`` (JSON text)."""
        params = {"periods": periods, "nearest": str(nearest).lower(), "format": "netcdf",
                  **_params(point)}  # fmt: skip
        return self._download(f"/studies/{study_id}/timeseries", params=params)

    # ------------------------------------------------------------------ the point store

    def points(self, *, page: int = 10_000, **query: Any) -> xr.Dataset:
        """Computed points of every study (``GET /points``), all pages, as a Dataset along
        ``point`` (parameters as coordinates, results as variables).

        ``query``: a value per parameter (``theta=0.3``, ``gap=0.1``), or a range
        (``gamma_r_min=1, gamma_r_max=2``), and ``modes``, ``coupling``, ``method``,
        ``outcome``, ``cells`` (chains of N cells; 1: the unit cell), ``version`` (``"all"``:
        every solver version), ``study``.
        """
        params = {**_params(query), "format": "netcdf", "limit": str(page)}
        parts: list[xr.Dataset] = []
        while True:
            headers: dict[str, str] = {}
            ds = self._download("/points", params, headers)
            if ds.sizes.get("point", 0):
                parts.append(ds)
            nxt = headers.get("x-next-after")
            if not nxt:
                break
            params["after"] = nxt
        if not parts:
            return ds
        return parts[0] if len(parts) == 1 else xr.concat(parts, dim="point")

    def health(self) -> dict[str, Any]:
        """``GET /health``."""
        return self._json("GET", "/health")

    def regressions(self) -> list[dict[str, Any]]:
        """Nightly regression runs, newest first."""
        return self._json("GET", "/regressions")["items"]

    def regression(self, reg_id: int) -> dict[str, Any]:
        """One nightly regression run, with its report once it has finished."""
        return self._json("GET", f"/regressions/{int(reg_id)}")

    def run_nightly(self) -> dict[str, Any]:
        """Start the nightly suite on the service, through its own job queue; returns the run's
        record (``regression(id)`` has the report once ``finished_at`` is set).

        Raises :class:`Conflict` while a run is in progress.
        """
        return self._json("POST", "/regressions")

    def record_regression(self, report: Mapping[str, Any], markdown: str = "") -> dict[str, Any]:
        """Catalogue the report of a suite run made elsewhere (``impactcell nightly --url``);
        returns its record, listed by ``regressions()`` like the service's own runs."""
        body = {"report": dict(report), "markdown": markdown}
        return self._json("POST", "/regressions/reports", json=body)


def _content_type(r: httpx.Response) -> str:
    """The media type of an answer, without parameters (``text/csv``)."""
    return r.headers.get("content-type", "").split(";")[0].strip().lower()


def _check_not_a_page(r: httpx.Response) -> None:
    """:class:`NotAService` for a web page: the API answers JSON, CSV, images or NetCDF."""
    if _content_type(r) in ("text/html", "application/xhtml+xml"):
        raise _not_a_service(r)


def _not_a_service(r: httpx.Response) -> NotAService:
    """One line for an answer that is not the service's, never its body (an HTML page)."""
    u = r.request.url
    kind = r.headers.get("content-type", "").split(";")[0].strip() or "no content type"
    return NotAService(
        r.status_code,
        f"{u.scheme}://{u.netloc.decode('ascii', 'replace')} is not an impactcell service: "
        f"{r.request.method} {u.path} answered HTTP {r.status_code} {r.reason_phrase} "
        f"with {kind}".rstrip(),
    )


def _raise_for(r: httpx.Response) -> None:
    """The error of an answer with status >= 400, carrying the server's message."""
    if r.status_code < 400:
        return
    try:
        body = r.json() if _content_type(r) == "application/json" else None
    except ValueError:
        body = None
    if not isinstance(body, dict) or "detail" not in body:
        # Every error of the service is JSON with a detail: this answer is another server's.
        raise _not_a_service(r)
    message = body["detail"] if isinstance(body["detail"], str) else json.dumps(body["detail"])
    problems = body.get("problems")
    fallback = ServerError if r.status_code >= 500 else ClientError
    cls = _BY_STATUS.get(r.status_code, fallback)
    raise cls(r.status_code, message, problems)


def _check_finite(obj: Any, path: str = "") -> None:
    """:class:`InvalidRequest` naming every NaN or infinite number's path, as the service would
    (JSON has no NaN: sent as is, the service could only say the body is not JSON)."""
    problems: list[dict[str, str]] = []

    def walk(o: Any, p: str) -> None:
        if isinstance(o, Mapping):
            for k, v in o.items():
                walk(v, f"{p}.{k}" if p else str(k))
        elif isinstance(o, list | tuple):
            for i, v in enumerate(o):
                walk(v, f"{p}.{i}" if p else str(i))
        elif isinstance(o, float | np.floating) and not math.isfinite(float(o)):
            problems.append({"path": p, "message": f"must be a finite number, got {float(o)!r}"})

    walk(obj, path)
    if problems:
        detail = "; ".join(f"{q['path']}: {q['message']}" for q in problems)
        raise InvalidRequest(422, detail, problems)


def _typed(values: Any, dtype: str) -> np.ndarray:
    """The ``values`` of a JSON slice as an array of its ``dtype`` (null -> NaN for floats)."""
    if dtype == "bool":
        return np.asarray(values, dtype=bool)
    if dtype == "int":
        return np.asarray(values, dtype=np.int64)
    if dtype == "str":
        return np.asarray(values, dtype=object)
    return np.asarray(_none_to_nan(values), dtype=float)


def _params(sel: Mapping[str, Any]) -> dict[str, str]:
    return {k: repr(float(v)) if isinstance(v, float) else str(v) for k, v in sel.items()}


# The service's NaN-safe JSON helpers live in service.studies.dataset; the client may not import
# service modules, so it keeps this tiny inverse (JSON null back to NaN) of its own.
def _none_to_nan(values: Any) -> Any:
    if isinstance(values, list):
        return [_none_to_nan(v) for v in values]
    return np.nan if values is None else values


def _bandgap_dataset(out: Mapping[str, Any]) -> xr.Dataset:
    x, y = out["x"], out.get("y")
    coords = {x: np.asarray(out["coords"][x], dtype=float)}
    dims: tuple[str, ...] = (x,)
    if y:
        coords[y] = np.asarray(out["coords"][y], dtype=float)
        dims = (y, x)
    info = out.get("variable") or {"name": "transmittance_db"}
    name = str(info["name"])
    values = np.asarray(_none_to_nan(out[name]), dtype=float)
    mask = np.asarray(out["attenuating"], dtype=bool)
    attrs = {"units": str(info.get("units", "dB")), "long_name": str(info.get("long_name", ""))}
    ds = xr.Dataset(
        {name: (dims, values, attrs), "attenuating": (dims, mask)},
        coords=coords,
        attrs={
            "variable": name,
            "threshold_db": out["threshold_db"],
            "x": x,
            "y": y or "",
            "edges": json.dumps(out["edges"]),
            "slice": json.dumps(out.get("slice", {})),
        },  # fmt: skip
    )
    for axis in (out.get("axes") or {}).values():  # units and long names of x and y
        if axis:
            ds[axis["name"]].attrs.update(units=axis["units"], long_name=axis["long_name"])
    for k, info in (out.get("slice") or {}).items():
        ds = ds.assign_coords({k: info["value"]})
    return ds


class _ProgressLine:
    """A one-line progress display on stderr (the standard library only: no tqdm here)."""

    def __init__(self) -> None:
        self.drawn = False

    def __call__(self, rec: Mapping[str, Any]) -> None:
        done, total = rec["points_done"], rec["points_total"]
        pct = 100.0 * done / total if total else 100.0
        why = f": {rec['error']}" if rec["status"] == "waiting" and rec.get("error") else ""
        sys.stderr.write(
            f"\r{rec['name']}: {pct:5.1f}% {done:,}/{total:,} pt [{rec['status']}{why}]"
        )
        sys.stderr.flush()
        self.drawn = True

    def close(self) -> None:
        if self.drawn:
            sys.stderr.write("\n")
            sys.stderr.flush()
