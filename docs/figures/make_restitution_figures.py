"""The restitution figure of docs/paper-comparison.md.

Writes ``docs/figures/restitution-gamma.png`` and ``docs/figures/restitution-gamma-map.png``::

    python docs/figures/make_restitution_figures.py [--data-dir DIR]

It runs the shipped study ``restitution-gamma`` (``service.local.run``; under a minute on two
cores, nothing when its results are in ``DIR``) and prints what the figures show: for each
coefficient of restitution e, the attenuation band (Γ < 0), Γ and the impacts per period at a
few frequencies, how many points ended irregular, the time on the stops and the energy the
impacts take.

``restitution-gamma.png``: Γ over γ_r for e = 0, 0.3, 0.6, 0.9 (the cell without stops
dashed); the contact episodes per period; the fraction of the period on a stop; the energy the
impacts take per period (both stops summed in each). ``restitution-gamma-map.png``: the map of
Γ − Γ_lin over γ_r × e (``impactcell plot RESULTS --kind impact-effect --y restitution``).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import worker  # noqa: F401  # first: pins the CPU target (worker/cpu.py), as the service does

# isort: split
import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import xarray as xr  # noqa: E402

from service.analysis.figures import figure as service_figure  # noqa: E402
from service.local import run  # noqa: E402
from service.studies.variables import outcome_names  # noqa: E402

HERE = Path(__file__).resolve().parent


def figure(ds: xr.Dataset, out: Path) -> None:
    """Γ, contact episodes, time on the stops and impact energy over γ_r, one line per e."""
    fig, axes = plt.subplots(2, 2, figsize=(10, 7))
    (left, right), (low_left, low_right) = axes
    g = ds.gamma_r.values
    cmap = matplotlib.colormaps["viridis"]
    es = ds.restitution.values
    for k, e in enumerate(es):
        row = ds.sel(restitution=e)
        color = cmap(k / max(len(es) - 1, 1) * 0.9)
        left.plot(g, row.transmittance_db.values, lw=1.0, marker=".", ms=3, color=color,
                  label=f"e = {e:g}")  # fmt: skip
        irregular = outcome_names(row.outcome) == "irregular"
        left.plot(g[irregular], row.transmittance_db.values[irregular], ls="none", marker="x",
                  ms=4, mew=0.6, color=color)  # fmt: skip
        right.plot(g, row.impacts_per_period.sum("stop").values, lw=1.0, color=color,
                   label=f"e = {e:g}")  # fmt: skip
        low_left.plot(g, 100 * row.contact_fraction.sum("stop").values, lw=1.0, color=color,
                      label=f"e = {e:g}")  # fmt: skip
        low_right.plot(g, row.impact_energy.sum("stop").values, lw=1.0, color=color,
                       label=f"e = {e:g}")  # fmt: skip
    left.plot(g, ds.transmittance_linear_db.isel(restitution=0).values, ls="--", lw=0.8,
              color="0.3", label="without stops")  # fmt: skip
    left.axhline(0.0, color="k", lw=0.6, ls=":")
    left.set(xlabel="γ_r", ylabel="Γ (dB)", title="transmittance (× irregular)")
    right.set(xlabel="γ_r", ylabel="contact episodes per period", yscale="log",
              title="impacts per period, both stops")  # fmt: skip
    low_left.set(xlabel="γ_r", ylabel="% of the period", title="time on the stops")
    low_right.set(xlabel="γ_r", ylabel="energy per period (model units)", yscale="log",
                  title="energy the impacts take")  # fmt: skip
    for ax in axes.flat:
        ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(out, dpi=130)
    print(f"wrote {out}")


def impact_map(ds: xr.Dataset, out: Path) -> None:
    """The service's impact-effect map over γ_r × e."""
    out.write_bytes(service_figure(ds, "impact-effect", y="restitution").image)
    print(f"wrote {out}")


def report(ds: xr.Dataset) -> None:
    """Each e's band, outcomes and values at a few frequencies."""
    g = ds.gamma_r.values
    for e in ds.restitution.values:
        row = ds.sel(restitution=e)
        t = row.transmittance_db.values
        names = outcome_names(row.outcome)
        counts = {o: int((names == o).sum()) for o in ("linear", "periodic", "irregular",
                                                       "unsettled", "failed")}  # fmt: skip
        band = g[t < 0]
        at = {float(x): (float(row.transmittance_db.sel(gamma_r=x)),
                         float(row.impacts_per_period.sel(gamma_r=x).sum()))
              for x in (0.6, 1.0, 1.4, 2.0, 3.0)}  # fmt: skip
        print(
            f"e = {e:g}: {counts}; Γ < 0 from γ_r {band.min():.2f}; "
            + ", ".join(f"γ_r {x:g}: {v:.2f} dB, {n:.1f} impacts" for x, (v, n) in at.items())
        )
    base = ds.transmittance_db.sel(restitution=0.0)
    for e in ds.restitution.values[1:]:
        d = ds.transmittance_db.sel(restitution=e) - base
        k = int(np.nanargmax(np.abs(d.values)))
        print(
            f"e = {e:g} − e = 0: largest |ΔΓ| {float(d[k]):+.2f} dB at γ_r {g[k]:.2f}; "
            f"median |ΔΓ| {float(np.nanmedian(np.abs(d.values))):.3f} dB"
        )
    ct = ds.contact_fraction.sum("stop")
    energy = ds.impact_energy.sum("stop")
    every = (ds.impacts_per_period.sum("stop") > 0).all("restitution")
    for e in ds.restitution.values:
        c = ct.sel(restitution=e).values[every.values]
        en = energy.sel(restitution=e).values[every.values]
        print(
            f"e = {e:g}: on the stops {100 * np.mean(c):.0f} % of the period (mean over the "
            f"{int(every.sum())} frequencies where every e impacts; median "
            f"{100 * np.median(c):.1f} %); impact energy per period median {np.median(en):.3g}"
        )


def main() -> None:
    """Run the study (or read its results) and draw the figure."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data-dir", type=Path, default=Path("data"))
    args = ap.parse_args()
    ds = run("restitution-gamma", data_dir=args.data_dir, progress=True)
    report(ds)
    figure(ds, HERE / "restitution-gamma.png")
    impact_map(ds, HERE / "restitution-gamma-map.png")


if __name__ == "__main__":
    main()
