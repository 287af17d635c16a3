"""service.client on its own (an httpx mock transport, no service): waiting and progress, the
service contract (cancel, delete, resume), typed slices, NetCDF time series, CSV and SVG."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest
import xarray as xr

from service.client import Client, InvalidRequest, NotFound, StudyFailed, StudyPage


def _client(statuses: list[str], total: int = 10) -> Client:
    """A client whose study ``abc123`` goes through ``statuses``, one per poll."""
    polls = iter(statuses)

    def handler(request: httpx.Request) -> httpx.Response:
        if request.url.path != "/studies/abc12345":
            return httpx.Response(404, json={"detail": f"no study {request.url.path}"})
        status = next(polls)
        done = total if status == "finished" else total // 2
        return httpx.Response(200, json={
            "id": "abc12345", "name": "mock", "status": status, "points_total": total,
            "points_done": done,
            "error": {"failed": "boom", "waiting": "the disk refused a write"}.get(status),
        })  # fmt: skip

    return Client("http://mock", token="", transport=httpx.MockTransport(handler))


def test_wait_draws_a_progress_line_on_stderr(capsys: pytest.CaptureFixture[str]) -> None:
    rec = _client(["running", "finished"]).wait("abc12345", poll=0)
    assert rec["status"] == "finished"
    err = capsys.readouterr().err
    assert "mock:  50.0% 5/10 pt [running]" in err
    assert err.endswith("mock: 100.0% 10/10 pt [finished]\n")


def test_wait_goes_on_through_an_outage_and_shows_why_it_waits(
    capsys: pytest.CaptureFixture[str],
) -> None:
    rec = _client(["running", "waiting", "running", "finished"]).wait("abc12345", poll=0)
    assert rec["status"] == "finished"
    assert "5/10 pt [waiting: the disk refused a write]" in capsys.readouterr().err


def test_wait_feeds_a_progress_callable_or_nothing(capsys: pytest.CaptureFixture[str]) -> None:
    seen: list[dict[str, Any]] = []
    _client(["queued", "running", "finished"]).wait("abc12345", progress=seen.append, poll=0)
    assert [r["status"] for r in seen] == ["queued", "running", "finished"]
    _client(["running", "finished"]).wait("abc12345", progress=False, poll=0)
    assert capsys.readouterr().err == ""


def test_wait_raises_for_a_failed_study_and_errors_by_status() -> None:
    with pytest.raises(StudyFailed, match="ended failed: boom"):
        _client(["running", "failed"]).wait("abc12345", progress=False, poll=0)
    with pytest.raises(NotFound, match="no study"):
        _client([]).get("ffff0000")


# --------------------------------------------------------------------------- the service contract


class Recorder:
    """A mock service that records requests and answers from a table of (method, path)."""

    def __init__(self, answers: dict[tuple[str, str], httpx.Response]) -> None:
        self.answers = answers
        self.seen: list[httpx.Request] = []

    def __call__(self, request: httpx.Request) -> httpx.Response:
        self.seen.append(request)
        key = (request.method, request.url.path)
        if key not in self.answers:
            return httpx.Response(404, json={"detail": f"no route {key}"})
        return self.answers[key]

    def client(self) -> Client:
        return Client("http://mock", token="", transport=httpx.MockTransport(self))


REC = {"id": "abc12345", "name": "mock", "status": "queued", "points_total": 4,
       "points_done": 0, "error": None}  # fmt: skip


def test_cancel_posts_delete_deletes_and_submit_can_resume() -> None:
    svc = Recorder({
        ("POST", "/studies/abc12345/cancel"): httpx.Response(200, json={**REC,
                                                                        "status": "cancelled"}),
        ("DELETE", "/studies/abc12345"): httpx.Response(204),
        ("POST", "/studies"): httpx.Response(200, json=REC),
    })  # fmt: skip
    c = svc.client()
    assert c.cancel("abc12345")["status"] == "cancelled"
    assert c.delete("abc12345") is None
    c.submit({"name": "x", "grid": {"gamma_r": 1.0}}, resume=True)
    c.submit({"name": "x", "grid": {"gamma_r": 1.0}})
    methods = [(r.method, r.url.path, r.url.params.get("resume")) for r in svc.seen]
    assert methods == [("POST", "/studies/abc12345/cancel", None),
                       ("DELETE", "/studies/abc12345", None), ("POST", "/studies", "true"),
                       ("POST", "/studies", None)]  # fmt: skip
    assert json.loads(svc.seen[2].content) == {"name": "x", "grid": {"gamma_r": 1.0}}


def test_submit_names_a_nan_before_sending(tmp_path: Path) -> None:
    svc = Recorder({})
    c = svc.client()
    d = {"name": "x", "grid": {"gamma_r": {"start": float("nan"), "stop": 2.0, "num": 3},
                               "gap": [0.1, float("inf")]}}  # fmt: skip
    with pytest.raises(InvalidRequest) as err:
        c.submit(d)
    assert [p["path"] for p in err.value.problems] == ["grid.gamma_r.start", "grid.gap.1"]
    assert "grid.gamma_r.start: must be a finite number, got nan" in str(err.value)
    f = tmp_path / "s.json"
    f.write_text('{"name": "x", "grid": {"theta": NaN}}', encoding="utf-8")
    with pytest.raises(InvalidRequest, match="grid.theta"):
        c.submit(f)
    assert svc.seen == []  # nothing was sent


def test_list_returns_a_page_with_the_total() -> None:
    body = {"items": [REC, {**REC, "id": "def67890"}], "total": 7, "limit": 2, "offset": 4}
    page = (
        Recorder({("GET", "/studies"): httpx.Response(200, json=body)})
        .client()
        .list(limit=2, offset=4)
    )
    assert isinstance(page, StudyPage) and isinstance(page, list)
    assert [r["id"] for r in page] == ["abc12345", "def67890"] and page == body["items"]
    assert (page.total, page.limit, page.offset) == (7, 2, 4)


def test_wait_on_a_cancelled_study_says_how_to_resume() -> None:
    with pytest.raises(StudyFailed) as err:
        _client(["running", "cancelled"]).wait("abc12345", progress=False, poll=0)
    text = str(err.value)
    assert "ended cancelled" in text and "Client.resume('abc12345')" in text
    assert "resume=True" in text and err.value.record["status"] == "cancelled"


def _slice(values: list[Any], dtype: str) -> httpx.Response:
    return httpx.Response(200, json={
        "variable": "v", "dtype": dtype, "units": "1", "long_name": "v", "dims": ["gamma_r"],
        "coords": {"gamma_r": [0.5, 1.0]}, "coord_dims": {"gamma_r": ["gamma_r"]},
        "scalars": {"gap": 0.1}, "values": values, "partial": False,
    })  # fmt: skip


@pytest.mark.parametrize(
    ("values", "dtype", "kind", "expect"),
    [
        (["", "diverged"], "str", "O", ["", "diverged"]),
        ([True, False], "bool", "b", [True, False]),
        ([3, 4], "int", "i", [3, 4]),
        ([1.5, None], "float", "f", [1.5, None]),
    ],
)
def test_data_keeps_the_type_of_values(values: list[Any], dtype: str, kind: str,
                                       expect: list[Any]) -> None:  # fmt: skip
    c = Recorder({("GET", "/studies/abc12345/data"): _slice(values, dtype)}).client()
    da = c.data("abc12345", variable="reason", gap=0.1)
    assert da.dtype.kind == kind and float(da["gap"]) == 0.1
    got = [None if isinstance(v, float) and np.isnan(v) else v for v in da.values.tolist()]
    assert got == expect


def test_timeseries_is_a_dataset_from_netcdf(tmp_path: Path) -> None:
    path = tmp_path / "ts.nc"
    xr.Dataset({"x": ("time", np.arange(4.0))}, coords={"time": np.linspace(0, 1, 4)},
               attrs={"point": "{}"}).to_netcdf(path, engine="netcdf4")  # fmt: skip
    svc = Recorder({("GET", "/studies/abc12345/timeseries"):
                    httpx.Response(200, content=path.read_bytes())})  # fmt: skip
    ds = svc.client().timeseries("abc12345", periods=3, gamma_r=1.0, gap=0.1)
    assert isinstance(ds, xr.Dataset) and ds["x"].values.tolist() == [0.0, 1.0, 2.0, 3.0]
    params = svc.seen[0].url.params
    assert params["format"] == "netcdf" and params["periods"] == "3" and params["gap"] == "0.1"


def test_csv_and_svg_methods() -> None:
    svc = Recorder({
        ("GET", "/studies/abc12345/data"): httpx.Response(200, text="gamma_r,v\n0.5,1.0\n"),
        ("GET", "/studies/abc12345/bandgap"): httpx.Response(200, text="gap,band\n"),
        ("GET", "/studies/abc12345/plots/bandgap.svg"): httpx.Response(200, content=b"<svg/>"),
    })  # fmt: skip
    c = svc.client()
    assert c.data_csv("abc12345", gap=0.1) == "gamma_r,v\n0.5,1.0\n"
    assert c.bandgap_csv("abc12345", theta=0.3) == "gap,band\n"
    assert c.plot("abc12345", "bandgap", fmt="svg") == b"<svg/>"
    svc.answers[("GET", "/studies/abc12345/bandgap")] = httpx.Response(200, json={"x": "gamma_r"})
    assert c.bandgap_json("abc12345", y="gap") == {"x": "gamma_r"}
    assert svc.seen[-1].url.params["y"] == "gap" and "format" not in svc.seen[-1].url.params
    assert [r.url.params.get("format") for r in svc.seen[:2]] == ["csv", "csv"]
    assert "x" not in svc.seen[1].url.params  # the service picks the default axes
    with pytest.raises(ValueError, match="png or svg"):
        c.plot("abc12345", "bandgap", fmt="pdf")


def test_a_streamed_download_raises_the_server_error_and_leaves_no_file(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("TMPDIR", str(tmp_path))
    import tempfile

    monkeypatch.setattr(tempfile, "tempdir", None)  # re-read TMPDIR
    c = Recorder({}).client()
    with pytest.raises(NotFound, match="no route"):
        c.dataset("abc12345")
    assert list(tmp_path.iterdir()) == []


def test_bandgap_map_of_another_variable_and_the_default_threshold() -> None:
    doc = {
        "x": "gamma_r", "y": None, "coords": {"gamma_r": [1.0, 2.0, 3.0]},
        "variable": {"name": "impact_effect_db", "units": "dB", "long_name": "impact effect"},
        "impact_effect_db": [-2.0, None, 0.5], "attenuating": [True, False, False],
        "threshold_db": -1.0, "edges": [{"y": None, "bands": [[1.0, 1.5]], "kinds": []}],
        "slice": {},
    }  # fmt: skip
    svc = Recorder({("GET", "/studies/abc12345/bandgap"): httpx.Response(200, json=doc)})
    c = svc.client()
    ds = c.bandgap_map("abc12345", variable="impact_effect_db")
    params = svc.seen[-1].url.params
    # no threshold sent: the service's default for the variable (-1 dB here) applies
    assert params["variable"] == "impact_effect_db" and "threshold_db" not in params
    assert ds.attrs["variable"] == "impact_effect_db" and ds.attrs["threshold_db"] == -1.0
    np.testing.assert_array_equal(ds["impact_effect_db"].values, [-2.0, np.nan, 0.5])
    assert ds["impact_effect_db"].attrs == {"units": "dB", "long_name": "impact effect"}
    c.bandgap_json("abc12345", threshold_db=0.5)
    params = svc.seen[-1].url.params
    assert params["threshold_db"] == "0.5" and params["variable"] == "transmittance_db"
    # an older service's document names no variable: it is Γ
    old = {k: v for k, v in doc.items() if k not in ("variable", "impact_effect_db")}
    old["transmittance_db"] = [1.0, 2.0, None]
    svc.answers[("GET", "/studies/abc12345/bandgap")] = httpx.Response(200, json=old)
    ds = c.bandgap_map("abc12345")
    assert ds.attrs["variable"] == "transmittance_db"
    np.testing.assert_array_equal(ds["transmittance_db"].values, [1.0, 2.0, np.nan])


def test_hysteresis_sends_only_what_is_given_and_plot_names_the_kind() -> None:
    doc = {"x": "gap", "branches": [{"label": "up"}, {"label": "down"}], "jumps": []}
    svc = Recorder({
        ("GET", "/studies/abc12345/hysteresis"): httpx.Response(200, json=doc),
        ("GET", "/studies/abc12345/plots/hysteresis.png"): httpx.Response(200, content=b"PNG"),
    })  # fmt: skip
    c = svc.client()
    assert c.hysteresis("abc12345") == doc
    params = svc.seen[-1].url.params
    # the service picks x (the swept axis) and its thresholds
    assert dict(params) == {"variable": "transmittance_db", "nearest": "false"}
    c.hysteresis("abc12345", x="gamma_r", jump_db=2.0, tol_db=0.1, direction="up", gap=0.3)
    params = svc.seen[-1].url.params
    assert (params["x"], params["jump_db"], params["tol_db"]) == ("gamma_r", "2.0", "0.1")
    assert params["direction"] == "up" and params["gap"] == "0.3"
    svc.answers[("GET", "/studies/abc12345/hysteresis")] = httpx.Response(200, text="branch\n")
    assert c.hysteresis_csv("abc12345", initial="rest") == "branch\n"
    assert svc.seen[-1].url.params["format"] == "csv"
    assert c.plot("abc12345", "hysteresis", tol_db=0.2) == b"PNG"
    assert svc.seen[-1].url.params["tol_db"] == "0.2"
    svc.answers[("GET", "/studies/abc12345/hysteresis")] = httpx.Response(
        422, json={"detail": "this study has no sweep or several starts: no hysteresis"}
    )
    with pytest.raises(InvalidRequest, match="no sweep or several starts"):
        c.hysteresis("abc12345")


def test_an_answer_that_is_not_the_services_is_not_a_service_error() -> None:
    from service.client import NotAService

    page = httpx.Response(200, html="<html><body>router login</body></html>")
    svc = Recorder({
        ("GET", "/studies/abc12345"): page,
        ("GET", "/studies"): httpx.Response(404, json={"error": "no such thing"}),
        ("GET", "/studies/abc12345/data"): httpx.Response(502, html="<h1>Bad gateway</h1>"),
    })  # fmt: skip
    c = svc.client()
    with pytest.raises(NotAService) as err:
        c.get("abc12345")
    assert str(err.value.message) == (
        "http://mock is not an impactcell service: GET /studies/abc12345 answered HTTP 200 OK "
        "with text/html"
    )
    with pytest.raises(NotAService, match="HTTP 404 Not Found with application/json"):
        c.list()  # JSON, but not the service's errors (they have a detail)
    with pytest.raises(NotAService, match="HTTP 502 Bad Gateway with text/html") as err:
        c.data_csv("abc12345")
    assert err.value.status == 502 and "Bad gateway" not in str(err.value)
