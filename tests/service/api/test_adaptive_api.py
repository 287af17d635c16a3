"""Adaptive studies through the service (issue 17): submitted, run on the cluster, their
located edges in ``/bandgap``, the client and the plots; no partial dataset while they run."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

from service.client import Client
from tests.service.api.test_api import make_app  # noqa: F401 - the fixture
from tests.service.helpers import Server
from tests.service.studies.test_adaptive_studies import adaptive_study


def test_an_unfinished_adaptive_study_has_no_dataset_yet(make_app: Any) -> None:  # noqa: F811
    with make_app() as app:  # no runner: the study stays queued
        rec = app.http.post("/studies", json=adaptive_study()).json()
        assert rec["points_total"] == 2 * 60  # lines × max_points: the most it may take
        for path in ("dataset", "bandgap", "data?theta=0.3"):
            r = app.http.get(f"/studies/{rec['id']}/{path}")
            assert r.status_code == 409, path
            assert "adaptive" in r.json()["detail"] and "GET /points?study=" in r.json()["detail"]


@pytest.mark.slow
def test_an_adaptive_study_through_the_service(tmp_path: Path, dask_address: str) -> None:
    srv = Server(tmp_path / "data", dask_address)
    try:
        with Client(srv.url) as c:
            rec = c.wait(c.submit(adaptive_study("service"))["id"], progress=False, timeout=300)
            assert rec["status"] == "finished"
            assert rec["points_done"] == rec["points_total"] == rec["points_computed"] <= 120
            ds = c.dataset(rec["id"])
            assert int(ds.sampled.sum()) == rec["points_total"]
            bands = c.bandgap_json(rec["id"], x="gamma_r", y="gap")
            kinds = {k for row in bands["edges"] for pair in row["kinds"] for k in pair}
            assert kinds <= {"located", "uncertain", "grid_end"} and "located" in kinds
            for row in bands["edges"]:
                located = ds.band_edges.sel(gap=row["y"]).values
                for start, stop in row["bands"]:
                    for x in (start, stop):
                        assert x in (3.0, 0.5) or np.any(np.isclose(located, x, rtol=0,
                                                                    atol=1e-12))  # fmt: skip
            png = c.plot(rec["id"], "bandgap", fmt="png")
            assert png[:8] == b"\x89PNG\r\n\x1a\n"
            pts = c.points(study=rec["id"])
            assert pts.sizes["point"] == rec["points_total"]
    finally:
        srv.stop()
