"""Results routes in process (TestClient, no cluster): partial datasets built incrementally,
the size cap of /data, CSV and SVG outputs, default axes of plots and /bandgap.

Chunks are written straight into the store with synthetic records (the numbers do not matter
here; tests/worker checks them), so no point is simulated.
"""

from __future__ import annotations

import csv
import io
import json
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from fastapi.testclient import TestClient

from service.api.app import create_app
from service.api.routes import results
from service.api.settings import Settings
from service.client import Client, InvalidRequest
from service.studies.chunks import StudyStore
from service.studies.dataset import results_from_records
from service.studies.schema import parse_study
from tests.service.helpers import AppTransport

# quick.yaml's axes (gamma_r × gap × theta), fewer frequencies.
QUICK = {
    "name": "quick-like",
    "grid": {
        "gamma_r": {"start": 0.1, "stop": 6.0, "num": 6},
        "gap": [0.1, 0.5, 2.0],
        "theta": [0.1, 0.3],
        "sigma": 0.05,
        "gamma_s": 1.0,
    },
}


def record(i: int, gamma: float | None = None) -> dict[str, Any]:
    """A synthetic linear point; Γ alternates sign so that maps have bands."""
    g = (-3.0 if i % 3 else 2.0) if gamma is None else gamma
    return {"outcome": "linear", "transmittance_db": g, "transmittance_db_se": None,
            "amplitude": 0.5, "theta_eff": 0.3 - i % 2, "theta_eff_slope": None,
            "response_period": 1, "impacts_per_period": [0.0, 0.0], "peak_impulse": 0.0,
            "floquet_multiplier": 0.1, "periods": 3, "steps": 10, "contact_steps": 0,
            "coarse_steps": 0, "steady_period": 2, "wall_s": 0.001,
            "reason": f"note {i}" if i % 5 == 0 else "", "failed": False}  # fmt: skip


class Served:
    """An app without the job runner, a study submitted to it and its store."""

    def __init__(self, root: Path, definition: dict[str, Any], **settings: Any) -> None:
        s = Settings(data_dir=root / "data", database_url=f"sqlite:///{root / 'cat.sqlite'}",
                     **settings)  # fmt: skip
        self.settings = s
        self.tc = TestClient(create_app(s, run_jobs=False))
        self.tc.__enter__()
        self.client = Client("http://testserver", token="", transport=AppTransport(self.tc))
        self.id = self.tc.post("/studies", json=definition).json()["id"]
        self.study = parse_study(definition)
        self.store = StudyStore(s.data_dir, self.study)
        self.store.prepare()

    def write(self, start: int, stop: int) -> None:
        self.store.write_chunk(start, stop, [record(i) for i in range(start, stop)])

    def get(self, path: str, **params: Any) -> Any:
        return self.tc.get(f"/studies/{self.id}{path}", params=params)

    def close(self) -> None:
        self.tc.__exit__(None, None, None)


def _reads(monkeypatch: pytest.MonkeyPatch) -> list[str]:
    """Record every chunk file the store reads."""
    seen: list[str] = []
    original = StudyStore._load_chunk

    def counting(self: StudyStore, path: Path) -> Any:
        seen.append(path.name)
        return original(self, path)

    monkeypatch.setattr(StudyStore, "_load_chunk", counting)
    return seen


def test_partial_dataset_reads_only_new_chunks(
    served: Served, monkeypatch: pytest.MonkeyPatch
) -> None:
    reads = _reads(monkeypatch)
    for a in range(0, 24, 6):
        served.write(a, a + 6)
    first = served.get("/dataset")
    assert first.status_code == 200 and first.headers["x-impactcell-partial"] == "1"
    assert len(reads) == 4
    again = served.get("/dataset")
    assert again.content == first.content and len(reads) == 4  # nothing read again
    served.write(24, 30)
    third = served.get("/dataset")
    assert reads[4:] == ["24-30.npz"]  # only the new chunk
    ds = served.client.dataset(served.id)
    assert int(ds.attrs["points_done"]) == 30 and int(ds["pending"].sum()) == 6
    assert third.content != first.content
    # The incremental dataset equals one built from scratch.
    cols, filled = served.store.collect_partial()
    fresh = results_from_records(served.study, cols, computed=filled)
    for name in ("transmittance_db", "reason", "outcome", "failed", "pending"):
        np.testing.assert_array_equal(ds[name].values, fresh[name].values)


def test_a_vanished_chunk_rebuilds_and_a_finished_file_is_served_as_is(served: Served) -> None:
    served.write(0, 6)
    served.write(6, 12)
    assert int(served.client.dataset(served.id).attrs["points_done"]) == 12
    (served.store.chunk_dir / "6-12.npz").unlink()  # a retry chunk removed for recomputation
    assert int(served.client.dataset(served.id).attrs["points_done"]) == 6
    assert list(served.store.folder.glob("partial-*.nc"))  # served from a file it wrote
    # Finished: the results file is streamed as it is, and the partial files are tidied.
    served.store.write_results(
        results_from_records(served.study, served.store.collect_partial()[0])
    )
    served.tc.app.state.catalogue.update_study(served.id, status="finished")
    r = served.get("/dataset")
    assert r.status_code == 200 and r.headers["x-impactcell-partial"] == "0"
    assert r.content == served.store.results_path.read_bytes()
    assert not list(served.store.folder.glob("partial-*.nc"))


def test_data_over_the_cap_is_422_naming_the_axes(
    served: Served, monkeypatch: pytest.MonkeyPatch
) -> None:
    served.write(0, 36)
    monkeypatch.setattr(results, "MAX_SLICE_VALUES", 10)
    r = served.get("/data")
    assert r.status_code == 422
    detail = r.json()["detail"]
    for text in ("36 values", "limit of 10", "gap (3 values)", "theta (2 values)",
                 "gamma_r (6 values)", f"/studies/{served.id}/dataset"):  # fmt: skip
        assert text in detail, detail
    assert served.get("/data", gap=0.1, theta=0.1).status_code == 200  # 6 values
    with pytest.raises(InvalidRequest, match="limit of 10"):
        served.client.data(served.id)


def test_data_csv_and_typed_json(served: Served) -> None:
    served.write(0, 36)
    r = served.get("/data", format="csv", theta=0.1)
    assert r.status_code == 200 and r.headers["content-type"].startswith("text/csv")
    rows = list(csv.DictReader(io.StringIO(r.text)))
    assert len(rows) == 18 and set(rows[0]) == {"gap", "gamma_r", "transmittance_db", "theta",
                                                "sigma", "gamma_s"}  # fmt: skip
    assert {row["theta"] for row in rows} == {"0.1"}
    assert rows[0]["transmittance_db"] == "2.0" and rows[1]["transmittance_db"] == "-3.0"
    outcome = served.get("/data", variable="outcome", format="csv", theta=0.1, gap=0.1).text
    assert [row["outcome"] for row in csv.DictReader(io.StringIO(outcome))] == ["linear"] * 6
    reason = served.client.data(served.id, variable="reason", theta=0.1, gap=0.1)
    assert reason.values[0] == "note 0" and reason.values[1] == ""
    failed = served.client.data(served.id, variable="failed", theta=0.1, gap=0.1)
    assert failed.dtype == bool and not failed.values.any()
    steps = served.client.data(served.id, variable="steps", theta=0.1, gap=0.1)
    assert steps.dtype.kind == "i" and (steps.values == 10).all()
    assert "theta" in served.client.data_csv(served.id, theta=0.3)


def test_data_serves_the_transient_flag_and_how_long_the_impacts_lasted(served: Served) -> None:
    recs = [record(i) for i in range(36)]
    for i in (1, 4):  # irregular beside an admissible impact-free response (constructed)
        recs[i].update(outcome="irregular", may_be_transient=True, impacting_periods=250 + i,
                       transmittance_db_se=0.05, response_period=0)  # fmt: skip
    served.store.write_chunk(0, 36, recs)
    flag = served.client.data(served.id, variable="may_be_transient", theta=0.1, gap=0.1)
    assert flag.dtype == bool and list(np.flatnonzero(flag.values)) == [1, 4]
    assert flag.attrs["flag_meanings"] == "not_flagged may_be_transient"
    lasted = served.get("/data", variable="impacting_periods", theta=0.1, gap=0.1).json()
    assert lasted["values"] == [None, 251, None, None, 254, None]


@pytest.mark.parametrize("kind", ["transmittance", "bandgap", "effective-mass"])
@pytest.mark.parametrize("fmt", ["png", "svg"])
def test_plots_need_no_parameters(served: Served, kind: str, fmt: str) -> None:
    served.write(0, 36)
    r = served.get(f"/plots/{kind}.{fmt}")
    assert r.status_code == 200, r.text
    fixed = json.loads(r.headers["x-impactcell-fixed"])
    if fmt == "png":
        assert r.headers["content-type"] == "image/png" and r.content[:4] == b"\x89PNG"
    else:
        assert r.headers["content-type"] == "image/svg+xml" and b"<svg" in r.content[:500]
        assert served.client.plot(served.id, kind, fmt="svg") == r.content
    assert fixed["x"] == "gamma_r"
    if kind == "effective-mass":
        assert fixed["y"] is None and fixed["fixed"] == {"gap": 0.1, "theta": 0.1}
    else:
        assert fixed["y"] == "gap" and fixed["fixed"] == {"theta": 0.1}
    # Given a selection, nothing more is fixed.
    r = served.get(f"/plots/{kind}.{fmt}", theta=0.3, gap=0.5)
    assert r.status_code == 200 and json.loads(r.headers["x-impactcell-fixed"])["fixed"] == {}


def test_the_advertised_plot_link_works(served: Served) -> None:
    served.write(0, 36)
    link = served.tc.get(f"/studies/{served.id}").json()["links"]["plots"]
    r = served.tc.get(link)
    assert r.status_code == 200 and r.content[:4] == b"\x89PNG"


def test_bandgap_defaults_match_the_plot_and_describe_themselves(served: Served) -> None:
    served.write(0, 36)
    out = served.get("/bandgap").json()
    plot = json.loads(served.get("/plots/bandgap.png").headers["x-impactcell-fixed"])
    assert (out["x"], out["y"]) == (plot["x"], plot["y"]) == ("gamma_r", "gap")
    assert out["axes"]["x"]["name"] == "gamma_r" and out["axes"]["y"]["values"] == [0.1, 0.5, 2.0]
    assert out["axes"]["y"]["long_name"].startswith("clearance")
    assert out["threshold"]["units"] == "dB" and out["variable"]["units"] == "dB"
    assert out["slice"]["theta"] == {"value": 0.1, "units": "1", "default": True,
                                     "long_name": "mass ratio theta = rho A l / m_o"}  # fmt: skip
    assert out["slice"]["sigma"]["default"] is False and out["study_id"] == served.id
    given = served.get("/bandgap", theta=0.3).json()
    assert given["slice"]["theta"]["value"] == 0.3 and not given["slice"]["theta"]["default"]
    ds = served.client.bandgap_map(served.id)
    assert ds.attrs["y"] == "gap" and float(ds["theta"]) == 0.1
    assert ds["gap"].attrs["units"] == "1" and json.loads(ds.attrs["slice"])["theta"]["default"]


def test_bandgap_csv_lists_every_band(served: Served) -> None:
    served.write(0, 36)
    text = served.client.bandgap_csv(served.id, theta=0.1)
    assert text == served.get("/bandgap", format="csv", theta=0.1).text
    rows = list(csv.DictReader(io.StringIO(text)))
    edges = served.get("/bandgap", theta=0.1).json()["edges"]
    assert len(rows) == sum(max(1, len(e["bands"])) for e in edges)
    first = edges[0]["bands"][0]
    assert float(rows[0]["start"]) == pytest.approx(first[0])
    assert float(rows[0]["stop"]) == pytest.approx(first[1])
    assert rows[0]["gap"] == "0.1" and rows[0]["threshold_db"] == "0.0"
    assert rows[0]["start_edge"] in ("crossing", "grid_end", "missing")


def test_bandgap_map_over_the_cap_is_422(served: Served, monkeypatch: pytest.MonkeyPatch) -> None:
    served.write(0, 36)
    monkeypatch.setattr(results, "MAX_SLICE_VALUES", 10)
    r = served.get("/bandgap")
    assert r.status_code == 422 and "18 values" in r.json()["detail"]


def test_one_axis_study_gives_a_1d_map(tmp_path: Path) -> None:
    d = {"name": "line", "grid": {"gamma_r": [0.5, 1.0, 1.5], "gap": 0.1, "theta": 0.3,
                                  "sigma": 0.05, "gamma_s": 1.0}}  # fmt: skip
    app = Served(tmp_path, d)
    try:
        app.write(0, 3)
        out = app.get("/bandgap").json()
        assert out["y"] is None and out["axes"]["y"] is None and len(out["edges"]) == 1
        r = app.get("/plots/transmittance.svg")
        assert r.status_code == 200 and json.loads(r.headers["x-impactcell-fixed"])["y"] is None
    finally:
        app.close()


def impact_record(i: int) -> dict[str, Any]:
    """A synthetic point with the linear reference: every third point impacts and attenuates
    2.5 dB more than the cell without stops."""
    rec = record(i)
    impacting = i % 3 == 1
    effect = -2.5 if impacting else 0.0
    rec.update(outcome="periodic" if impacting else "linear",
               transmittance_linear_db=rec["transmittance_db"] - effect,
               impact_effect_db=effect)  # fmt: skip
    return rec


def test_bandgap_of_the_impact_effect_and_the_linear_reference(served: Served) -> None:
    served.store.write_chunk(0, 36, [impact_record(i) for i in range(36)])
    out = served.get("/bandgap", variable="impact_effect_db", theta=0.1).json()
    assert out["variable"]["name"] == "impact_effect_db" and out["variable"]["units"] == "dB"
    assert (
        out["threshold"]["value"] == -1.0
        and "more than the same cell" in (out["threshold"]["meaning"])
    )
    values = np.array(out["impact_effect_db"])  # gap × gamma_r
    np.testing.assert_array_equal(out["attenuating"], values < -1.0)
    # points 1, 4 of each spectrum impact: bands around γ_r[1] and γ_r[4] in every row
    gr = np.array(out["axes"]["x"]["values"])
    for row in out["edges"]:
        assert len(row["bands"]) == 2
        assert row["bands"][0][0] < gr[1] < row["bands"][0][1] < gr[2]
    lin = served.client.bandgap_map(served.id, theta=0.1, variable="transmittance_linear_db")
    assert lin.attrs["variable"] == "transmittance_linear_db" and lin.attrs["threshold_db"] == 0.0
    assert lin["transmittance_linear_db"].attrs["units"] == "dB"
    # the client's own threshold is sent; none means the service's default for the variable
    eff = served.client.bandgap_json(served.id, theta=0.1, variable="impact_effect_db",
                                     threshold_db=-3.0)  # fmt: skip
    assert eff["threshold_db"] == -3.0 and not any(e["bands"] for e in eff["edges"])
    csv_text = served.client.bandgap_csv(served.id, theta=0.1, variable="impact_effect_db")
    assert csv_text.splitlines()[1].split(",")[6] == "-1.0"  # threshold_db column
    r = served.get("/bandgap", variable="theta_eff")
    assert r.status_code == 422 and "impact_effect_db" in r.text
    for fmt in ("png", "svg"):
        p = served.get(f"/plots/bandgap.{fmt}", variable="impact_effect_db")
        assert p.status_code == 200, p.text
    png = served.client.plot(served.id, "bandgap", variable="impact_effect_db", theta=0.1)
    assert png[:4] == b"\x89PNG" and png != served.client.plot(served.id, "bandgap", theta=0.1)
    # reference=linear: measured against the cell without stops, the same map
    ref = served.get("/bandgap", reference="linear", theta=0.1).json()
    assert ref["variable"]["name"] == "impact_effect_db" and ref["edges"] == out["edges"]
    assert served.get("/plots/bandgap.png", reference="linear", theta=0.1).content == (
        served.get("/plots/bandgap.png", variable="impact_effect_db", theta=0.1).content
    )
    bad = served.get("/bandgap", reference="linear", variable="transmittance_linear_db")
    assert bad.status_code == 422 and "reference=linear" in bad.json()["detail"]


def test_the_map_variables_of_the_route_are_those_of_the_analysis() -> None:
    import typing

    from service.analysis.bands import MAP_VARIABLES

    assert typing.get_args(results.MapVariable) == tuple(MAP_VARIABLES)


def test_datasets_carry_the_reference_and_chunks_from_before_it_still_collate(
    served: Served,
) -> None:
    served.store.write_chunk(0, 18, [impact_record(i) for i in range(18)])
    # a chunk written before the linear reference existed: the same file without its columns
    served.store.write_chunk(18, 36, [impact_record(i) for i in range(18, 36)])
    path = served.store.chunk_dir / "18-36.npz"
    with np.load(path) as z:  # nor its SHA-256 (chunk files of then had none)
        old = {k: z[k] for k in z.files if k not in ("transmittance_linear_db",
                                                    "impact_effect_db", "_sha256")}  # fmt: skip
    with open(path, "wb") as fh:
        np.savez(fh, **old)
    ds = served.client.dataset(served.id)
    for name in ("transmittance_linear_db", "impact_effect_db"):
        assert ds[name].attrs["units"] == "dB" and ds[name].attrs["long_name"]
    flat = ds["impact_effect_db"].transpose("gap", "theta", "gamma_r").values.ravel()
    assert np.isnan(flat[18:]).all() and np.isfinite(flat[:18]).all()
    assert (flat[:18][[i % 3 == 1 for i in range(18)]] == -2.5).all()
    assert served.get("/bandgap", variable="impact_effect_db", theta=0.3).status_code == 200
    cols, _ = served.store.collect_partial()
    assert np.isnan(cols["transmittance_linear_db"][18:]).all()
