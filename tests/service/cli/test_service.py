"""``impactcell serve | submit | status | demo`` against real servers on 127.0.0.1."""

from __future__ import annotations

import json
from collections.abc import Iterator
from pathlib import Path

import pytest
import xarray as xr
import yaml

from service.api.server import ServerThread
from service.api.settings import Settings
from service.cli import main
from tests.service.helpers import tiny_study


@pytest.fixture
def server(tmp_path: Path, dask_address: str) -> Iterator[ServerThread]:
    s = Settings(host="127.0.0.1", port=0, data_dir=tmp_path / "data", scheduler=dask_address,
                 api_token="tok")  # fmt: skip
    srv = ServerThread(s).start()
    yield srv
    srv.stop()


def test_submit_wait_and_status(server: ServerThread, tmp_path: Path, capsys) -> None:
    f = tmp_path / "s.yaml"
    f.write_text(yaml.safe_dump(tiny_study(name="cli-sub", num=4)))
    args = ["--url", server.url, "--token", "tok"]
    assert main(["submit", str(f), *args, "--wait", "--no-progress"]) == 0
    out = capsys.readouterr().out
    sid = out.split()[0]
    assert "cli-sub" in out and "finished" in out
    assert main(["status", sid, *args, "--json"]) == 0
    rec = json.loads(capsys.readouterr().out)
    assert rec["status"] == "finished" and rec["points_done"] == 8
    assert main(["status", *args]) == 0
    assert sid in capsys.readouterr().out


def test_submit_reports_problems_and_auth(server: ServerThread, tmp_path: Path, capsys) -> None:
    bad = tiny_study()
    bad["grid"]["theta"] = -1
    f = tmp_path / "bad.yaml"
    f.write_text(yaml.safe_dump(bad))
    assert main(["submit", str(f), "--url", server.url, "--token", "tok"]) == 2
    err = capsys.readouterr().err
    assert "grid.theta" in err
    assert main(["status", "--url", server.url, "--token", "wrong"]) == 2
    assert "bearer token" in capsys.readouterr().err


def test_serve_rejects_bad_settings(capsys, monkeypatch) -> None:
    monkeypatch.setenv("IMPACTCELL_NIGHTLY_CRON", "every night")
    assert main(["serve", "--port", "0"]) == 2
    assert "nightly_cron" in capsys.readouterr().err


@pytest.mark.slow  # the demo study on an embedded cluster
def test_demo_writes_map_and_dataset(tmp_path: Path, capsys) -> None:
    f = tmp_path / "demo.yaml"
    d = tiny_study(name="demo-small", num=10, gaps=(0.1, 0.5))
    f.write_text(yaml.safe_dump(d))
    out = tmp_path / "out"
    assert main(["demo", "--study", str(f), "--out", str(out), "--workers", "1",
                 "--no-progress"]) == 0  # fmt: skip
    text = capsys.readouterr().out
    assert str(out) in text and "gap 0.1" in text
    png = (out / "bandgap.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n"
    ds = xr.open_dataset(out / "demo-small.nc")
    assert ds.sizes["gamma_r"] == 10 and ds.sizes["gap"] == 2
    ds.close()
    doc = json.loads((out / "bandgap.json").read_text())  # self-describing
    assert [e["y"] for e in doc["edges"]] == [0.1, 0.5]
    assert doc["variable"]["name"] == "transmittance_db" and doc["threshold"]["value"] == 0.0
    assert (doc["x"], doc["y"]) == ("gamma_r", "gap") and doc["axes"]["y"] is not None
    # what the impacts add: the impact-effect map and a line per gap
    assert (out / "impact_effect.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    effect = json.loads((out / "impact_effect.json").read_text())
    assert effect["variable"]["name"] == "impact_effect_db" and effect["threshold_db"] == -1.0
    assert text.count("impacts add > 1 dB of attenuation for γ_r in") == 2
    ds = xr.open_dataset(out / "demo-small.nc")
    assert ds["impact_effect_db"].attrs["units"] == "dB"
    ds.close()


def test_demo_lines_say_what_the_impacts_add() -> None:
    from service.cli.service import _demo_lines

    def doc(name: str, values: list, bands: list) -> dict:
        edges = [{"y": g, "bands": b} for g, b in zip((0.1, 0.5), bands, strict=True)]
        return {"x": "gamma_r", "coords": {"gamma_r": [1.0, 2.0, 3.0, 4.0]}, name: values,
                "edges": edges}  # fmt: skip

    gamma = doc("transmittance_db", [], [[[1.5, 4.0]], [[2.5, 4.0]]])
    lin = doc("transmittance_linear_db", [], [[[2.5, 4.0]], [[2.5, 4.0]]])
    # gap 0.1: impacts add 3 dB at γ_r 2 (a wider band); gap 0.5: they take 2 dB away at 3
    effect = doc("impact_effect_db", [[0.0, -3.0, 0.0, 0.0], [0.0, 0.0, 2.0, None]],
                 [[[1.33, 2.67]], []])  # fmt: skip
    lines = _demo_lines(gamma, lin, effect)
    assert lines[0] == (
        "  gap 0.1: Γ < 0 dB for γ_r in 1.5–4; without stops 2.5–4; impacts add > 1 dB of "
        "attenuation for γ_r in 1.33–2.67, remove > 1 dB in none"
    )
    assert lines[1].endswith("add > 1 dB of attenuation for γ_r in none, remove > 1 dB in 2.5–3")


def test_serve_never_prints_the_database_password(capsys, monkeypatch) -> None:
    import uvicorn

    monkeypatch.setattr(uvicorn, "run", lambda *a, **kw: None)  # the banner, not the server
    # port 1 of the loopback: no server; serve says so (exit 1) before starting uvicorn
    url = "postgresql+psycopg://impactcell:s3cret@127.0.0.1:1/impactcell"
    assert main(["serve", "--port", "0", "--database-url", url]) == 1
    err = capsys.readouterr().err
    assert "catalogue postgresql+psycopg://impactcell:***@127.0.0.1:1/impactcell" in err
    assert "s3cret" not in err
