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


# --------------------------------------------------------------------------- what figures show


def _with_outcomes() -> xr.Dataset:
    """The synthetic results with outcomes (a few irregular, unsettled and failed points at
    known places), the linear reference and the impact effect."""
    ds = _synthetic()
    shape = ds["transmittance_db"].shape
    codes = np.zeros(shape, dtype=np.int8)  # linear
    codes[:, :, 20:25] = 1  # periodic
    codes[0, 1, [30, 31, 32]] = 2  # irregular at θ = 0.3, gap 0.1
    codes[3, 1, 40] = 2
    codes[1, 1, 45] = 3  # unsettled
    codes[2, 1, 10] = 4  # failed: the NaN of _synthetic
    ds["outcome"] = (
        ds["transmittance_db"].dims,
        codes,
        {"flag_values": np.arange(5, dtype=np.int8),
         "flag_meanings": "linear periodic irregular unsettled failed"},
    )  # fmt: skip
    lin = ds["transmittance_db"].isel(gap=-1, drop=True) + 3.0  # independent of the gap
    ds["transmittance_linear_db"] = lin.broadcast_like(ds["transmittance_db"]).transpose(
        *ds["transmittance_db"].dims
    )
    ds["impact_effect_db"] = ds["transmittance_db"] - ds["transmittance_linear_db"]
    return ds


def _legend_texts(legend) -> list[str]:
    return [t.get_text() for t in legend.get_texts()]


def _gid(ax, gid: str) -> list:
    return [a for a in ax.get_lines() if a.get_gid() == gid]


def test_transmittance_marks_and_counts_outcomes_and_draws_the_linear_reference() -> None:
    from service.analysis.plots import transmittance_figure

    ds = _with_outcomes()
    fig = transmittance_figure(ds, {"theta": 0.3}, hue="gap")
    ax = fig.axes[0]
    texts = _legend_texts(ax.get_legend())
    assert "irregular (4)" in texts and "unsettled (1)" in texts and "failed (1)" in texts
    assert "Γ_lin: the cell without stops" in texts
    (irr,) = _gid(ax, "outcome-irregular")
    gr = ds["gamma_r"].values
    # on the curve, at the right points: x and Γ of the irregular points
    np.testing.assert_allclose(sorted(irr.get_xdata()), sorted([*gr[[30, 31, 32]], gr[40]]))
    g = ds["transmittance_db"].sel(theta=0.3).values
    np.testing.assert_allclose(sorted(irr.get_ydata()), sorted([*g[0, [30, 31, 32]], g[3, 40]]))
    (unset,) = _gid(ax, "outcome-unsettled")
    assert unset.get_marker() != irr.get_marker() and list(unset.get_xdata()) == [gr[45]]
    (fail,) = _gid(ax, "outcome-failed")  # no value: on the strip at the bottom of the axes
    assert list(fail.get_xdata()) == [gr[10]] and fail.get_transform() != ax.transData
    assert len({irr.get_marker(), unset.get_marker(), fail.get_marker()}) == 3
    # one thin dashed reference line per hue value, in the colour of that hue's curve
    refs = _gid(ax, "linear-reference")
    assert len(refs) == 5 and all(r.get_linestyle() == "--" for r in refs)
    curves = [ln for ln in ax.get_lines() if str(ln.get_label()).startswith("g̃ = ")]
    assert [c.get_color() for c in curves] == [r.get_color() for r in refs]
    lin = ds["transmittance_linear_db"].sel(theta=0.3, gap=0.5).values
    np.testing.assert_allclose(refs[2].get_ydata(), lin)
    # without outcomes (an old file): the NaN is still counted, as failed
    old = _with_outcomes().drop_vars(["outcome", "transmittance_linear_db"])
    ax_old = transmittance_figure(old, {"theta": 0.3}, hue="gap").axes[0]
    texts_old = _legend_texts(ax_old.get_legend())
    assert "failed (1)" in texts_old and not any("irregular" in t for t in texts_old)
    assert not _gid(ax_old, "linear-reference")


def test_effective_mass_marks_outcomes() -> None:
    from service.analysis.plots import effective_mass_figure

    ax = effective_mass_figure(_with_outcomes(), {"theta": 0.3, "gap": 0.1}).axes[0]
    assert "irregular (3)" in _legend_texts(ax.get_legend())
    (irr,) = _gid(ax, "outcome-irregular")
    assert len(irr.get_xdata()) == 3


def test_the_effective_mass_figure_says_which_estimator_is_which() -> None:
    from service.analysis.plots import effective_mass_figure

    ds = _synthetic()
    ax = effective_mass_figure(ds, {"theta": 0.3, "gap": 0.1}).axes[0]
    texts = _legend_texts(ax.get_legend())
    assert any(t.startswith("θ_eff, effective mass (first harmonic") for t in texts)
    assert any(t.startswith("θ_ps, phase-portrait slope") for t in texts)
    assert not any(t.startswith("θ_eff") and "slope" in t for t in texts)
    assert "first harmonic" in ax.get_title() and "θ_ps" in ax.get_ylabel()
    (ps,) = _gid(ax, "phase-portrait-ratio")
    np.testing.assert_allclose(ps.get_ydata(), ds["theta_eff_slope"].sel(theta=0.3, gap=0.1))
    alone = effective_mass_figure(ds.drop_vars("theta_eff_slope"), {"theta": 0.3, "gap": 0.1})
    assert "θ_ps" not in alone.axes[0].get_ylabel()


def test_may_be_transient_points_have_a_mark_and_legend_entry_of_their_own() -> None:
    from service.analysis.plots import (
        MARKS,
        TRANSIENT,
        bandgap_figure,
        effective_mass_figure,
        transmittance_figure,
    )

    ds = _with_outcomes()
    flag = np.zeros(ds["outcome"].shape, dtype=bool)
    flag[0, 1, [31, 32]] = True  # two of the three irregular points at θ 0.3, gap 0.1
    flag[0, 1, 5] = True  # a flag on a linear point is not an irregular one: not marked
    ds["may_be_transient"] = (ds["outcome"].dims, flag)
    gr = ds["gamma_r"].values
    assert MARKS[TRANSIENT]["marker"] != MARKS["irregular"]["marker"]
    for ax in (
        transmittance_figure(ds, {"theta": 0.3, "gap": 0.1}).axes[0],
        effective_mass_figure(ds, {"theta": 0.3, "gap": 0.1}).axes[0],
    ):
        texts = _legend_texts(ax.get_legend())
        assert "irregular (1)" in texts and "irregular, may be transient (2)" in texts
        (tr,) = _gid(ax, f"outcome-{TRANSIENT}")
        np.testing.assert_allclose(sorted(tr.get_xdata()), gr[[31, 32]])
        (irr,) = _gid(ax, "outcome-irregular")
        np.testing.assert_allclose(irr.get_xdata(), gr[[30]])
    m = bandgap_map(ds, "gamma_r", "gap", threshold_db=-3, sel={"theta": 0.3})
    fig = bandgap_figure(m)
    assert "irregular, may be transient (2)" in _legend_texts(fig.legends[0])
    (tr,) = _gid(fig.axes[0], f"outcome-{TRANSIENT}")
    assert set(tr.get_ydata()) == {0.1}


def test_bandgap_hatching_is_on_the_cells_of_the_mesh() -> None:
    from matplotlib.collections import QuadMesh
    from matplotlib.patches import Rectangle

    from service.analysis.plots import bandgap_figure, cell_edges

    ds = _with_outcomes()
    # an irregular grid: cell edges are midpoints, not a fixed step
    ds = ds.isel(gamma_r=np.r_[0:20, 20:59:3])
    m = bandgap_map(ds, "gamma_r", "gap", threshold_db=-3, sel={"theta": 0.3})
    fig = bandgap_figure(m)
    ax = fig.axes[0]
    xv, yv = m["gamma_r"].values, m["gap"].values
    xe, ye = cell_edges(xv), cell_edges(yv)
    np.testing.assert_allclose(xe[1:-1], 0.5 * (xv[1:] + xv[:-1]))
    (mesh,) = [c for c in ax.collections if isinstance(c, QuadMesh)]
    coords = mesh.get_coordinates()  # (ny + 1, nx + 1, 2): the cell corners drawn
    np.testing.assert_allclose(coords[0, :, 0], xe)
    np.testing.assert_allclose(coords[:, 0, 1], ye)
    hatched = np.zeros((yv.size, xv.size), dtype=bool)
    rects = [p for p in ax.patches if isinstance(p, Rectangle) and p.get_gid() == "attenuating"]
    assert rects and all(r.get_hatch() == "//" for r in rects)
    for r in rects:
        x0, y0, w, h = r.get_x(), r.get_y(), r.get_width(), r.get_height()
        i0 = int(np.flatnonzero(np.isclose(xe, x0, rtol=0, atol=1e-12))[0])
        i1 = int(np.flatnonzero(np.isclose(xe, x0 + w, rtol=0, atol=1e-12))[0])
        j = int(np.flatnonzero(np.isclose(ye, y0, rtol=0, atol=1e-12))[0])
        assert np.isclose(ye[j + 1], y0 + h, rtol=0, atol=1e-12)  # exactly one row of cells
        assert not hatched[j, i0:i1].any()  # no cell hatched twice
        hatched[j, i0:i1] = True
    np.testing.assert_array_equal(hatched, m["attenuating"].transpose("gap", "gamma_r").values)
    # outcome marks at cell centres, counted in the figure legend
    texts = _legend_texts(fig.legends[0])
    n_irr = int((m["outcome"] == 2).sum())
    assert n_irr and f"irregular ({n_irr})" in texts
    assert any(t.startswith("Γ < -3 dB (") for t in texts)
    (irr,) = _gid(ax, "outcome-irregular")
    assert set(irr.get_xdata()) <= set(xv) and set(irr.get_ydata()) <= set(yv)
    # PNG and SVG of the same figure
    _check_png(bandgap_png(m))
    assert bandgap_png(m, fmt="svg").lstrip().startswith(b"<?xml")


def test_bandgap_of_the_impact_effect_and_the_linear_cell() -> None:
    from service.analysis.plots import bandgap_figure

    ds = _with_outcomes()
    m = bandgap_map(ds, "gamma_r", "gap", sel={"theta": 0.3}, variable="impact_effect_db")
    assert m.attrs["threshold_db"] == -1.0 and m.attrs["variable"] == "impact_effect_db"
    fig = bandgap_figure(m)
    assert "where impacts add attenuation (Γ − Γ_lin < -1 dB)" in fig.axes[0].get_title()
    (mesh,) = fig.axes[0].collections[:1]
    assert mesh.norm.vcenter == 0.0  # no effect is the neutral colour
    lin = bandgap_map(ds, "gamma_r", "gap", sel={"theta": 0.3}, variable="transmittance_linear_db")
    assert "cell without stops" in bandgap_figure(lin).axes[0].get_title()
    _check_png(bandgap_png(m))
    assert b"<svg" in bandgap_png(lin, fmt="svg")


def test_points_not_computed_yet_are_counted_not_marked_as_failed() -> None:
    from service.analysis.plots import bandgap_figure, transmittance_figure

    ds = _with_outcomes()
    pending = np.zeros(ds["transmittance_db"].shape, dtype=bool)
    pending[:, 1, 50:] = True  # a partial dataset: the end of every θ = 0.3 spectrum
    ds["pending"] = (ds["transmittance_db"].dims, pending)
    ds["transmittance_db"] = ds["transmittance_db"].where(~ds["pending"])
    ds["outcome"] = ds["outcome"].where(~ds["pending"], 4).astype(np.int8)  # stored as failed
    fig = bandgap_figure(bandgap_map(ds, "gamma_r", "gap", sel={"theta": 0.3}))
    texts = _legend_texts(fig.legends[0])
    assert "not computed yet (45)" in texts and "failed (1)" in texts
    ax = transmittance_figure(ds, {"theta": 0.3}, hue="gap").axes[0]
    texts = _legend_texts(ax.get_legend())
    assert "not computed yet (45)" in texts and "failed (1)" in texts


def test_band_edges_are_drawn_above_the_outcome_marks() -> None:
    from service.analysis.plots import bandgap_figure

    ds = _with_outcomes()
    m = bandgap_map(ds, "gamma_r", "gap", threshold_db=-3, sel={"theta": 0.3})
    ax = bandgap_figure(m).axes[0]
    edges = _gid(ax, "band-edge")
    marks = [ln for ln in ax.get_lines() if str(ln.get_gid()).startswith("outcome-")]
    assert edges and marks
    assert min(e.get_zorder() for e in edges) > max(k.get_zorder() for k in marks)


def _si() -> xr.Dataset:
    """Γ over gap_m × frequency_hz of a physical study, its cell's SI constants 0-d."""
    f = np.linspace(50.0, 400.0, 8)
    gaps = np.array([1e-4, 3e-4, 5e-4])
    gamma = -np.outer(gaps * 1e4, np.ones(f.size)) - f / 100
    return xr.Dataset(
        {"transmittance_db": (("gap_m", "frequency_hz"), gamma, {"units": "dB"})},
        coords={
            "gap_m": ("gap_m", gaps, {"units": "m"}),
            "frequency_hz": ("frequency_hz", f, {"units": "Hz"}),
            "length_m": ((), 0.03, {"units": "m"}),
            "youngs_modulus_pa": ((), 2e11, {"units": "Pa"}),
            "outer_mass_kg": ((), 0.02, {"units": "kg"}),
            "damping_ratio": ((), 0.02, {"units": "1"}),
        },
    )


def test_si_axes_read_in_prefixed_units() -> None:
    from service.analysis.plots import bandgap_figure, transmittance_figure

    ds = _si()
    ax = transmittance_figure(ds, hue="gap_m", fixed={"length_m": 0.03}).axes[0]
    texts = _legend_texts(ax.get_legend())
    assert {"gap = 0.1 mm", "gap = 0.3 mm", "gap = 0.5 mm"} <= set(texts)
    assert not any("gap_m" in t or "0.0005" in t for t in texts)
    title = ax.get_title()
    assert "E = 200 GPa" in title and "outer mass = 20 g" in title
    assert "damping ratio = 0.02" in title  # dimensionless: no unit
    assert title.endswith("by default at the first value: length = 30 mm")
    assert title.count("length") == 1
    assert ax.get_xlabel() == "frequency (Hz)"
    # a map with the gap along y: its label and ticks in mm
    ax = bandgap_figure(bandgap_map(ds, "frequency_hz", "gap_m", threshold_db=-3)).axes[0]
    assert ax.get_ylabel() == "gap (mm)"
    assert ax.yaxis.get_major_formatter()(3e-4, 0) == "0.3"
