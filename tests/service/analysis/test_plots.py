"""service.analysis.plots: every figure is a PNG of the fixed size, errors are AnalysisErrors."""

from __future__ import annotations

import io
import re
import threading
from pathlib import Path

import numpy as np
import pytest
import xarray as xr

from service.analysis.bands import bandgap_map
from service.analysis.plots import DPI, FIGSIZE, bandgap_png, effective_mass_png, transmittance_png
from service.analysis.selection import AnalysisError
from service.studies.dataset import open_results
from service.studies.runner import run_study
from service.studies.schema import parse_study

PNG = b"\x89PNG\r\n\x1a\n"
WIDTH, HEIGHT = round(FIGSIZE[0] * DPI), round(FIGSIZE[1] * DPI)


def _check_png(data: bytes) -> None:
    import matplotlib.image as mpimg

    assert data[:8] == PNG
    assert len(data) > 10_000
    img = mpimg.imread(io.BytesIO(data), format="png")
    assert img.shape[:2] == (HEIGHT, WIDTH)
    assert np.ptp(img[..., :3]) > 0.5  # not a blank canvas


def _synthetic() -> xr.Dataset:
    """Γ and θ_eff over gap × theta × gamma_r like the paper's Figure 5(a), one failed point."""
    gr = np.round(np.linspace(0.2, 6.0, 59), 12)
    gap = np.array([0.1, 0.3, 0.5, 0.7, 1.0])
    theta = np.array([0.1, 0.3])
    g = 10 * np.cos(1.3 * gr) * np.exp(-gr / 6)
    gamma = g[None, None, :] - 5 * gap[:, None, None] - theta[None, :, None]
    gamma[2, 1, 10] = np.nan
    te = 1 / (1 - gr**2 + 0.02)  # a resonance at γ_r = 1, negative above it
    teff = np.broadcast_to(te, gamma.shape).copy()
    dims = ("gap", "theta", "gamma_r")
    return xr.Dataset(
        {
            "transmittance_db": (dims, gamma, {"units": "dB"}),
            "theta_eff": (dims, teff, {"units": "1"}),
            "theta_eff_slope": (dims, 0.8 * teff, {"units": "1"}),
        },
        coords={
            "gap": ("gap", gap, {"units": "1"}),
            "theta": ("theta", theta, {"units": "1"}),
            "gamma_r": ("gamma_r", gr, {"units": "1"}),
            "sigma": ((), 0.05, {"units": "1"}),
            "gamma_s": ((), 1.0, {"units": "1"}),
        },
    )


def test_matplotlib_only_here() -> None:
    import matplotlib

    assert matplotlib.get_backend().lower() == "agg"
    root = Path(__file__).resolve().parents[3] / "service"
    imports = re.compile(r"^\s*(import|from)\s+matplotlib", re.MULTILINE)
    users = sorted(
        p.relative_to(root).as_posix()
        for p in root.rglob("*.py")
        if imports.search(p.read_text("utf-8"))
    )
    assert users == ["analysis/plots.py"]
    # The object API only: no pyplot (global figure state) in the plotting module.
    assert not re.search(
        r"(import|from)\s+matplotlib\.pyplot|import\s+pyplot|plt\.",
        (root / "analysis" / "plots.py").read_text("utf-8"),
    )


def test_transmittance_png() -> None:
    ds = _synthetic()
    _check_png(transmittance_png(ds, {"theta": 0.3}, x="gamma_r", hue="gap"))
    _check_png(transmittance_png(ds, {"theta": 0.3, "gap": 0.5}))  # x defaults to gamma_r


def test_transmittance_png_frequency_axis() -> None:
    f = np.linspace(10.0, 40.0, 31)
    amp = np.array([0.25e-3, 0.5e-3, 1e-3])
    gamma = 6 * np.cos(f / 5)[None, :] - 1e3 * amp[:, None]
    ds = xr.Dataset(
        {"transmittance_db": (("base_amplitude_m", "frequency_hz"), gamma, {"units": "dB"})},
        coords={
            "base_amplitude_m": ("base_amplitude_m", amp, {"units": "m"}),
            "frequency_hz": ("frequency_hz", f, {"units": "Hz"}),
            "gamma_r": ("frequency_hz", f / 23.06, {"units": "1"}),
        },
    )
    _check_png(transmittance_png(ds, hue="base_amplitude_m"))
    _check_png(bandgap_png(bandgap_map(ds, "frequency_hz", "base_amplitude_m")))


def test_bandgap_png_2d_and_1d() -> None:
    ds = _synthetic()
    _check_png(bandgap_png(bandgap_map(ds, "gamma_r", "gap", threshold_db=-3, sel={"theta": 0.3})))
    _check_png(bandgap_png(bandgap_map(ds, "gamma_r", sel={"theta": 0.1, "gap": 0.5})))
    # No band anywhere and everything attenuating: still a figure.
    _check_png(bandgap_png(bandgap_map(ds, "gamma_r", "gap", threshold_db=-90, sel={"theta": 0.1})))
    _check_png(bandgap_png(bandgap_map(ds, "gamma_r", "gap", threshold_db=90, sel={"theta": 0.1})))


def test_effective_mass_png() -> None:
    ds = _synthetic()
    both = effective_mass_png(ds, {"theta": 0.3, "gap": 0.1}, x="gamma_r")
    _check_png(both)
    # Without the phase-portrait slope (a second line and legend entry fewer), and with a huge
    # resonance peak (symlog axis).
    one = effective_mass_png(ds.drop_vars("theta_eff_slope"), {"theta": 0.3, "gap": 0.1})
    _check_png(one)
    assert one != both
    # A slope missing everywhere (no phase portrait): drawn without it, as if absent.
    none = ds.copy(deep=True)
    none["theta_eff_slope"][:] = np.nan
    assert effective_mass_png(none, {"theta": 0.3, "gap": 0.1}) == one
    big = ds.drop_vars("theta_eff_slope").copy(deep=True)
    big["theta_eff"][..., 8] = 1e7
    _check_png(effective_mass_png(big, {"theta": 0.3, "gap": 0.1}))


def test_plot_errors_are_analysis_errors() -> None:
    ds = _synthetic()
    with pytest.raises(AnalysisError, match="missing: theta"):
        transmittance_png(ds, {}, hue="gap")
    with pytest.raises(AnalysisError, match="theta=0.35 is not a coordinate value"):
        effective_mass_png(ds, {"theta": 0.35, "gap": 0.1})
    with pytest.raises(AnalysisError, match="axis 'omega'"):
        transmittance_png(ds, {"theta": 0.3}, x="omega", hue="gap")
    with pytest.raises(AnalysisError, match="x is required"):
        transmittance_png(ds.rename(gamma_r="w"), {"theta": 0.3, "gap": 0.1})
    # nearest picks θ = 0.3.
    _check_png(effective_mass_png(ds, {"theta": 0.35, "gap": 0.1}, nearest=True))


def test_threads_draw_independently() -> None:
    ds = _synthetic()
    ref = transmittance_png(ds, {"theta": 0.3}, hue="gap")
    out: list[bytes] = []
    errors: list[BaseException] = []

    def draw() -> None:
        try:
            out.append(transmittance_png(ds, {"theta": 0.3}, hue="gap"))
        except BaseException as exc:  # pragma: no cover - reported below
            errors.append(exc)

    threads = [threading.Thread(target=draw) for _ in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert not errors and len(out) == 4
    assert all(o == ref for o in out)


def test_real_study_pngs(tmp_path: Path) -> None:
    study = parse_study(
        {
            "name": "plots",
            "solver": {"steps_per_period": 256, "max_periods": 60, "window": 5},
            "grid": {
                "gamma_r": {"start": 0.5, "stop": 4.0, "num": 8},
                "gap": [0.1, 0.6],
                "theta": 0.3,
                "sigma": 0.05,
                "gamma_s": 1.0,
            },
        }
    )
    ds = open_results(run_study(study, tmp_path, serial=True).path)
    _check_png(transmittance_png(ds, hue="gap"))
    _check_png(bandgap_png(bandgap_map(ds, "gamma_r", "gap")))
    _check_png(effective_mass_png(ds, {"gap": 0.1}))
