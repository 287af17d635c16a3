"""The experiment mode (docs/experiment.md): base amplitude per frequency, amplitudes in metres."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml

from service.studies.chunks import record_columns
from service.studies.dataset import results_from_records
from service.studies.files import StudyFileError, read_study_file
from service.studies.schema import StudyError, load_study, parse_study, study_from_canonical
from service.studies.specs import PhysicalSpec
from worker.simulate import simulate_chunk

ROOT = Path(__file__).resolve().parents[3]
FREQS = [12.0, 23.0, 42.0]
AMPS = [2.0e-3, 1.0e-3, 4.0e-4]

# Table 1 in SI, and the mapping of docs/model.md §8 written out by hand (not PhysicalCell's).
SI = {"length_m": 0.15, "width_m": 0.01, "thickness_m": 0.0025, "density_kg_m3": 1250.0,
      "youngs_modulus_pa": 4.583e7, "outer_mass_kg": 0.01667, "spring_n_m": 350.0,
      "gap_m": 0.001}  # fmt: skip


def _by_hand(f: float, u: float, xi: float) -> dict[str, float]:
    """θ, σ, γ_s, γ_r, ξ, g̃1, g̃2 of the Table 1 cell at frequency f and base amplitude u."""
    L, b, h, rho, E = 0.15, 0.01, 0.0025, 1250.0, 4.583e7  # noqa: N806 - the paper's symbols
    m_o, k, g = 0.01667, 350.0, 0.001
    beam_mass = rho * b * h * L
    w_m = math.sqrt(k / m_o)
    theta = beam_mass / m_o
    return {
        "theta": theta,
        "sigma": E * b * h**3 / 12.0 / (beam_mass * L**3 * w_m**2),
        "gamma_s": 1.0,
        "gamma_r": 2.0 * math.pi * f / w_m,
        "xi": xi,
        "g1": g * theta / u,
        "g2": g * theta / u,
    }


def _study(**physical: Any) -> dict[str, Any]:
    return {
        "name": "pf",
        "physical": {**SI, "damping_ratio": 0.03, **physical},
        "grid": {"damping_ratio": [0.01, 0.05], "frequency_hz": list(FREQS)},
    }


def _problems(d: dict[str, Any]) -> dict[str, str]:
    with pytest.raises(StudyError) as info:
        parse_study(d)
    return dict(info.value.problems)


def _write_table(path: Path, rows: list[tuple[float, float]], note: str = "") -> None:
    text = f"# {note}\n" if note else ""
    text += "frequency_hz,base_amplitude_m\n" + "".join(f"{f!r},{u!r}\n" for f, u in rows)
    path.write_text(text)


def _study_file(folder: Path, table: str = "amps.csv") -> Path:
    d = _study(base_amplitude_table=table)
    path = folder / "study.yaml"
    path.write_text(yaml.safe_dump(d))
    return path


# --------------------------------------------------------------------------- the mapping


def _check_points(study: Any, amps: list[float]) -> None:
    # Points are C order over (damping_ratio, frequency_hz): frequency varies fastest, so a
    # misaligned amplitude shows at the second damping ratio too.
    points = list(study.iter_points())
    assert len(points) == 2 * len(FREQS)
    for i, xi in enumerate([0.01, 0.05]):
        for j, f in enumerate(FREQS):
            got = points[i * len(FREQS) + j]
            want = _by_hand(f, amps[j], xi)
            for k, v in want.items():
                assert got[k] == pytest.approx(v, rel=1e-12), (f, k)
            assert got["modes"] == 5 and got["coupling"] == "paper"


def test_a_list_per_frequency_maps_each_point_with_its_own_amplitude() -> None:
    study = parse_study(_study(base_amplitude_per_frequency_m=AMPS))
    _check_points(study, AMPS)
    # g̃ differs by frequency (different U_g), as a constant amplitude would not give.
    assert len({p["g1"] for p in study.points(0, 3)}) == 3


def test_a_table_maps_like_the_list_whatever_its_row_order() -> None:
    rows = {"frequency_hz": FREQS[::-1], "base_amplitude_m": AMPS[::-1]}
    study = parse_study(_study(base_amplitude_table=rows))
    _check_points(study, AMPS)
    np.testing.assert_array_equal(study.base_amplitudes_m(), AMPS)


def test_a_table_file_is_read_relative_to_the_study_file(tmp_path: Path) -> None:
    _write_table(tmp_path / "amps.csv", [(42.0, AMPS[2]), (12.0, AMPS[0]), (23.0, AMPS[1])])
    study = load_study(_study_file(tmp_path))
    _check_points(study, AMPS)
    table = study.canonical()["physical"]["base_amplitude_table"]
    assert table == {"file": "amps.csv", "frequency_hz": [42.0, 12.0, 23.0],
                     "base_amplitude_m": [AMPS[2], AMPS[0], AMPS[1]]}  # fmt: skip


def test_a_range_frequency_axis_takes_a_list_in_its_order() -> None:
    d = _study(base_amplitude_per_frequency_m=[1e-3, 2e-3, 3e-3, 4e-3])
    d["grid"]["frequency_hz"] = {"start": 10.0, "stop": 40.0, "num": 4}
    points = list(parse_study(d).iter_points())
    for j, (f, u) in enumerate(
        zip([10.0, 20.0, 30.0, 40.0], [1e-3, 2e-3, 3e-3, 4e-3], strict=True)
    ):
        assert points[4 + j]["g1"] == pytest.approx(_by_hand(f, u, 0.05)["g1"], rel=1e-12)
        assert points[4 + j]["gamma_r"] == pytest.approx(_by_hand(f, u, 0.05)["gamma_r"])


def test_amplitudes_a_over_omega_squared_equal_a_base_acceleration() -> None:
    a = 21.0
    amps = [a / (2.0 * math.pi * f) ** 2 for f in FREQS]
    table = parse_study(_study(base_amplitude_per_frequency_m=amps))
    accel = parse_study(_study(base_acceleration_m_s2=a))
    for p, q in zip(table.iter_points(), accel.iter_points(), strict=True):
        assert p == pytest.approx(q, rel=1e-12)


def test_the_shipped_example_reads_its_table() -> None:
    # Its CSV holds a / (2 pi f)^2 for a = 21 m/s^2 rounded to 4 digits (the file says so).
    path = ROOT / "studies" / "examples" / "experiment-table1-per-frequency.yaml"
    study = load_study(path)
    d = read_study_file(path)
    del d["physical"]["base_amplitude_table"]
    accel = parse_study({**d, "physical": {**d["physical"], "base_acceleration_m_s2": 21.0}})
    assert study.size == 20
    for p, q in zip(study.iter_points(), accel.iter_points(), strict=True):
        assert p["g1"] == pytest.approx(q["g1"], rel=5e-4)  # 4 significant digits
        assert p["g1"] != pytest.approx(q["g1"], rel=1e-9)  # and not more: it is the file
        assert p["gamma_r"] == q["gamma_r"]


# --------------------------------------------------------------------------- validation


def test_a_list_of_the_wrong_length_names_both_sizes() -> None:
    got = _problems(_study(base_amplitude_per_frequency_m=AMPS[:2]))
    msg = got["physical.base_amplitude_per_frequency_m"]
    assert "has 2 values, but grid.frequency_hz has 3" in msg
    assert "one amplitude per frequency, in the order of grid.frequency_hz" in msg


@pytest.mark.parametrize(("bad", "expected"), [
    (-1e-3, "base_amplitude_per_frequency_m[1] must be > 0, got -0.001"),
    (0.0, "base_amplitude_per_frequency_m[1] must be > 0, got 0.0"),
    (1e3, "base_amplitude_per_frequency_m[1] must be <= 100, got 1000.0; allowed range"),
])  # fmt: skip
def test_a_bad_amplitude_is_named_by_its_index(bad: float, expected: str) -> None:
    got = _problems(_study(base_amplitude_per_frequency_m=[1e-3, bad, 1e-3]))
    assert expected in got["physical.base_amplitude_per_frequency_m"]
    assert len(got) == 1, got


def test_a_table_must_have_exactly_the_grids_frequencies() -> None:
    missing = {"frequency_hz": [12.0, 42.0], "base_amplitude_m": [1e-3, 1e-3]}
    msg = _problems(_study(base_amplitude_table=missing))["physical.base_amplitude_table"]
    assert "grid.frequency_hz has 23 Hz, which the table has no row for" in msg
    assert "its 2 rows span 12 … 42 Hz" in msg
    extra = {"frequency_hz": [*FREQS, 25.5], "base_amplitude_m": [1e-3] * 4}
    msg = _problems(_study(base_amplitude_table=extra))["physical.base_amplitude_table"]
    assert "table rows frequency_hz[3] = 25.5 Hz are not on grid.frequency_hz" in msg
    # Matching allows the 12 digits grid coordinates keep, not a different frequency.
    near = {"frequency_hz": [12.0 * (1 + 1e-12), 23.0, 42.0], "base_amplitude_m": AMPS}
    assert parse_study(_study(base_amplitude_table=near)).size == 6
    off = {"frequency_hz": [12.001, 23.0, 42.0], "base_amplitude_m": AMPS}
    with pytest.raises(StudyError) as info:
        parse_study(_study(base_amplitude_table=off))
    ((p1, m1), (p2, m2)) = info.value.problems  # both sides of the mismatch
    assert p1 == p2 == "physical.base_amplitude_table"
    assert "grid.frequency_hz has 12 Hz, which the table has no row for" in m1
    assert "table rows frequency_hz[0] = 12.001 Hz are not on grid.frequency_hz" in m2


@pytest.mark.parametrize(("rows", "path", "expected"), [
    ({"frequency_hz": FREQS, "base_amplitude_m": AMPS[:2]}, "physical.base_amplitude_table",
     "frequency_hz has 3 values and base_amplitude_m 2"),
    ({"frequency_hz": [12.0, 12.0, 42.0], "base_amplitude_m": AMPS},
     "physical.base_amplitude_table.frequency_hz",
     "frequencies must be distinct, got 12 Hz twice"),
    ({"frequency_hz": FREQS, "base_amplitude_m": [1e-3, -2e-3, 1e-3]},
     "physical.base_amplitude_table.base_amplitude_m",
     "base_amplitude_m[1] must be > 0, got -0.002"),
    ({"frequency_hz": [12.0, -23.0, 42.0], "base_amplitude_m": AMPS},
     "physical.base_amplitude_table.frequency_hz", "frequency_hz[1] must be > 0, got -23.0"),
    ("amps.csv", "physical.base_amplitude_table",
     "got the file name 'amps.csv', but a table file is read only from a study file"),
])  # fmt: skip
def test_a_bad_table_names_the_field_and_value(rows: Any, path: str, expected: str) -> None:
    got = _problems(_study(base_amplitude_table=rows))
    assert expected in got[path], got
    assert len(got) == 1, got  # and only that: not also "no excitation given"


def test_exactly_one_excitation() -> None:
    got = _problems(_study(base_amplitude_per_frequency_m=AMPS, base_amplitude_m=1e-3))
    msg = got["physical.base_amplitude_m"]
    assert msg.startswith("give exactly one of base_amplitude_m, base_acceleration_m_s2, "
                          "base_amplitude_per_frequency_m, base_amplitude_table")  # fmt: skip
    assert msg.endswith("got base_amplitude_m, base_amplitude_per_frequency_m")
    # A study without the new fields keeps its message.
    got = _problems(_study())
    assert got["physical.base_amplitude_m"] == (
        "give exactly one of base_amplitude_m and base_acceleration_m_s2, got neither"
    )


def test_per_frequency_amplitudes_are_checked_for_the_model_ranges() -> None:
    # g̃ = gθ/U_g: a 10 m gap over 1 pm is 2.8e12, beyond the model's 1e12.
    d = _study(base_amplitude_per_frequency_m=[1e-3, 1e-12, 1e-3], gap_m=10.0)
    msg = _problems(d)["physical"]
    assert "base_amplitude_m=1e-12" in msg and "the model's g1 must be <= 1e+12" in msg


def test_table_file_errors_name_file_line_and_column(tmp_path: Path) -> None:
    path = _study_file(tmp_path)
    with pytest.raises(StudyFileError, match=r"base_amplitude_table: cannot read table file "
                       r".*amps\.csv: No such file"):  # fmt: skip
        load_study(path)
    (tmp_path / "amps.csv").write_text("frequency_hz,amplitude_m\n12,0.001\n")
    with pytest.raises(StudyFileError, match="line 1: the header must name the columns "
                       "frequency_hz, base_amplitude_m; got frequency_hz, amplitude_m, "
                       "missing base_amplitude_m"):  # fmt: skip
        load_study(path)
    (tmp_path / "amps.csv").write_text("# note\nfrequency_hz,base_amplitude_m\n12,1mm\n")
    with pytest.raises(StudyFileError, match="line 3: base_amplitude_m must be a finite number, "
                       "got '1mm'"):  # fmt: skip
        load_study(path)
    (tmp_path / "amps.csv").write_text("frequency_hz,base_amplitude_m\n12,nan\n")
    with pytest.raises(StudyFileError, match="line 2: base_amplitude_m must be a finite number"):
        load_study(path)


# --------------------------------------------------------------------------- identity


def test_the_table_files_content_is_part_of_the_id(tmp_path: Path) -> None:
    rows = list(zip(FREQS, AMPS, strict=True))
    _write_table(tmp_path / "amps.csv", rows)
    path = _study_file(tmp_path)
    first = load_study(path)
    # Unchanged numbers keep the id: the same file again, with another note, or reordered
    # columns (the rows' content is what is hashed, not the text).
    assert load_study(path).id == first.id
    _write_table(tmp_path / "amps.csv", rows, note="measured 2026-11-22, run 2")
    assert load_study(path).id == first.id
    (tmp_path / "amps.csv").write_text(
        "base_amplitude_m,frequency_hz\n" + "".join(f"{u!r},{f!r}\n" for f, u in rows)
    )
    assert load_study(path).id == first.id
    # One number changed: another study.
    _write_table(tmp_path / "amps.csv", [*rows[:2], (42.0, 4.1e-4)])
    changed = load_study(path)
    assert changed.id != first.id
    assert changed.points(2, 3)[0]["g1"] != first.points(2, 3)[0]["g1"]


def test_a_canonical_definition_needs_no_table_file(tmp_path: Path) -> None:
    _write_table(tmp_path / "amps.csv", list(zip(FREQS, AMPS, strict=True)))
    study = load_study(_study_file(tmp_path))
    (tmp_path / "amps.csv").unlink()  # the catalogue and results files keep the rows
    again = study_from_canonical(json.loads(study.canonical_json()))
    assert again.id == study.id
    assert list(again.iter_points()) == list(study.iter_points())


def test_the_new_fields_do_not_touch_existing_ids() -> None:
    # exclude_none: a study without them has the canonical form it always had.
    d = _study(base_amplitude_m=1e-3)
    assert "base_amplitude_table" not in parse_study(d).canonical()["physical"]
    schema = PhysicalSpec.model_json_schema()
    for field in ("base_amplitude_per_frequency_m", "base_amplitude_table"):
        assert field in schema["properties"]
    desc = schema["properties"]["base_amplitude_per_frequency_m"]["description"]
    assert "Allowed: in [1e-12, 100]" in desc


# --------------------------------------------------------------------------- metres


def _dataset(study: Any, amplitudes: np.ndarray) -> Any:
    records = [{"outcome": "periodic", "amplitude": float(a), "failed": False} for a in amplitudes]
    return results_from_records(study, record_columns(records), created="2026-01-01T00:00:00+00:00")


def test_amplitude_m_is_amplitude_times_b_at_each_point() -> None:
    study = parse_study(_study(base_amplitude_per_frequency_m=AMPS))
    amplitude = np.array([1.5, 2.0, 0.5, 3.0, 0.25, 1.0])
    ds = _dataset(study, amplitude)
    assert ds["amplitude_m"].attrs["units"] == "m"
    assert ds["amplitude_m"].dims == ("damping_ratio", "frequency_hz")
    for i, xi in enumerate([0.01, 0.05]):
        for j, f in enumerate(FREQS):
            hand = _by_hand(f, AMPS[j], xi)
            b = AMPS[j] / (hand["theta"] * hand["gamma_s"])  # B = U_g / (θ γ_s)
            got = float(ds["amplitude_m"].sel(damping_ratio=xi, frequency_hz=f))
            assert got == pytest.approx(amplitude[i * 3 + j] * b, rel=1e-12)
    # U_g of each point is a coordinate along the frequency axis.
    assert ds["base_amplitude_m"].dims == ("frequency_hz",)
    np.testing.assert_array_equal(ds["base_amplitude_m"].values, AMPS)
    assert ds["base_amplitude_m"].attrs["units"] == "m"


def test_amplitude_m_of_a_failed_point_is_missing() -> None:
    study = parse_study(_study(base_amplitude_m=1e-3))
    records = [{"outcome": "periodic", "amplitude": 1.0, "failed": False}] * 5 + [
        {"outcome": "failed", "amplitude": None, "failed": True, "reason": "x"}
    ]
    ds = results_from_records(study, record_columns(records))
    values = ds["amplitude_m"].values.ravel()
    assert np.isnan(values[-1]) and np.all(np.isfinite(values[:-1]))


def test_amplitude_m_over_u_g_is_the_transmittance() -> None:
    # Eq. 33 (x / U_g) against Eq. 32, through the solver: three points, a second or so.
    d = _study(base_amplitude_per_frequency_m=AMPS)
    d["grid"]["damping_ratio"] = 0.03
    study = parse_study(d)
    records = simulate_chunk(study.points(0, 3), study.solver.model_dump())
    ds = results_from_records(study, record_columns(records))
    gamma = 20.0 * np.log10(ds["amplitude_m"] / ds["base_amplitude_m"])
    np.testing.assert_allclose(gamma, ds["transmittance_db"], rtol=0, atol=1e-9)
    assert np.all(np.isfinite(ds["transmittance_db"]))
