"""Physical (SI) description of the unit cell and its mapping to the model's parameters.

The simulator works in the non-dimensional variables of the paper's Eq. 30 (docs/model.md §3).
Experiments, and anyone reasoning about a real cell, think in metres, kilograms and hertz.
This module is the one place where that translation happens, following docs/model.md §8:

- the beam's reference frequency is chosen as the outer mass's, ``ω_b = ω_m``, so ``γ_s = 1``;
- ``θ = ρAL / m_o``, ``σ = EI / (ρA L⁴ ω_m²)``, ``γ_r = Ω / ω_m`` with ``Ω = 2πf``;
- ``g̃ = g / B`` with ``B = U_g / (θ γ_s) = U_g / θ``, ``U_g`` the base displacement amplitude;
- the transmittance ``Γ`` needs no conversion (Eq. 33 equals Eq. 32 under this scaling).

Because ``U_g`` enters the gaps, a cell driven at a fixed base *acceleration* amplitude ``a``
(what a shaker controller and an accelerometer deliver) has ``U_g = a / Ω²`` and therefore
different non-dimensional gaps at every frequency; :meth:`PhysicalCell.to_model` takes the
frequency for that reason.
"""

from __future__ import annotations

import math
from dataclasses import MISSING, dataclass, field, fields
from typing import Any

import numpy as np
from numpy.typing import NDArray

from worker.checks import check_field, check_fields, nonnegative, positive
from worker.model.modal import betas

__all__ = [
    "BASE_AMPLITUDE_M",
    "CELL_FIELDS",
    "FREQUENCY_HZ",
    "TABLE1_FREQUENCIES_HZ",
    "PhysicalCell",
]

# The measured plan of the paper's experiment (Sec. 3): 12–22 Hz by 2, 23–30 Hz by 1,
# 32–42 Hz by 2. Written out rather than generated so that the 20 values can be read off.
TABLE1_FREQUENCIES_HZ: tuple[float, ...] = (
    12.0, 14.0, 16.0, 18.0, 20.0, 22.0,
    23.0, 24.0, 25.0, 26.0, 27.0, 28.0, 29.0, 30.0,
    32.0, 34.0, 36.0, 38.0, 40.0, 42.0,
)  # fmt: skip


# Field metadata (worker.checks): the allowed values, written once, read by the validation
# below and by the study schema. ``gt``/``ge`` 0 is where the quantity makes sense; the other
# bounds are generous physical ranges (a MEMS cantilever to a building-sized rig), so that a
# unit slip (mm typed as m, GPa as Pa) or a 1e308 is refused while any real cell passes.
# Each ``why`` says the range (the study schema shows it).
def _si(lo: float, hi: float, why: str, *, zero: bool = False) -> dict[str, Any]:
    if zero:  # zero is meaningful (a pinned tip, no damping)
        return {"ge": 0.0, "le": hi, "why": why}
    return {"gt": 0.0, "ge": lo, "le": hi, "why": why}


_LENGTH = _si(1e-9, 1e3, "a beam dimension: 1 nm (a nanobeam's thickness) to 1 km")
_DENSITY = _si(1.0, 1e5, "1 kg/m³ (aerogel) to 1e5 kg/m³, above every solid (osmium 22,590)")
_MODULUS = _si(1e3, 1e13, "1 kPa (soft gels) to 1e13 Pa, above every solid (diamond ~1.2e12)")
_MASS = _si(1e-15, 1e6, "1e-15 kg (a MEMS proof mass is ~1e-12) to 1000 t")
_SPRING = _si(1e-6, 1e12, "1 µN/m to 1 TN/m, spanning MEMS suspensions to stiff mounts")
_DAMPING = _si(0.0, 10.0, "0 (undamped) to 10, ten times critical", zero=True)
_GAP = _si(0.0, 1e3, "0 (the tip pinned) to 1 km, far beyond any 'no stops' cell", zero=True)
_AMPLITUDE = _si(1e-12, 100.0, "1 pm to 100 m of base displacement")
_ACCELERATION = _si(1e-9, 1e7, "1 nm/s² to 1e7 m/s² (a million g, beyond shock testing)")
_OPT = {"optional": True}
#: The excitation frequency's rule (the argument of :meth:`PhysicalCell.to_model`).
FREQUENCY_HZ: dict[str, Any] = _si(1e-6, 1e9, "1 µHz to 1 GHz (MEMS resonators)")
#: The base displacement amplitude's rule: ``base_amplitude_m`` and every value of a
#: per-frequency amplitude list or table (a study gives ``U_g`` per frequency by setting
#: ``base_amplitude_m`` point by point).
BASE_AMPLITUDE_M: dict[str, Any] = _AMPLITUDE


@dataclass(frozen=True, kw_only=True)
class PhysicalCell:
    """A beam-in-mass unit cell described in SI units.

    All fields are keyword-only: a dozen floats in positional order invite silent swaps
    (width for thickness) that no validation could catch.

    Parameters
    ----------
    length_m : float
        Free length ``L`` of the cantilever, in [1e-9, 1e3] m.
    width_m : float
        Width (breadth) ``b`` of the rectangular cross-section, in [1e-9, 1e3] m.
    thickness_m : float
        Thickness ``h`` of the cross-section in the bending direction, in [1e-9, 1e3] m; the
        second moment of area is ``I = b h³ / 12`` and the area ``A = b h``.
    density_kg_m3 : float
        Beam density ``ρ``, in [1, 1e5] kg/m³.
    youngs_modulus_pa : float
        Beam Young's modulus ``E``, in [1e3, 1e13] Pa.
    outer_mass_kg : float
        Total rigid outer mass ``m_o``, in [1e-15, 1e6] kg, including anything rigidly
        attached to it (an accelerometer, for instance); see :meth:`from_added_mass`.
    spring_n_m : float
        Stiffness ``k`` of the spring between base and outer mass, in [1e-6, 1e12] N/m.
    gap_m : float or None
        Clearance between the beam tip and each stop, in [0, 1e3] m (0 pins the tip).
        Required unless both ``gap1_m`` and ``gap2_m`` are given.
    damping_ratio : float, optional
        ``ξ`` in [0, 10]: the outer dashpot is ``c = 2 ξ ω_m m_o`` (and, per docs/model.md §3,
        the beam's Rayleigh ratio unless the model is given another). Default 0.
    gap1_m, gap2_m : float or None, optional
        Clearances to stop 1 and stop 2 when they differ, in [0, 1e3] m; each defaults to ``gap_m``.
        Read the resolved pair from :attr:`gaps_m`.
    base_amplitude_m : float or None, optional
        Base displacement amplitude ``U_g``, in [1e-12, 100] m, the same at every frequency.
    base_acceleration_m_s2 : float or None, optional
        Base acceleration amplitude ``a``, in [1e-9, 1e7] m/s², the same at every frequency; then
        ``U_g = a / Ω²``. Exactly one of ``base_amplitude_m`` and ``base_acceleration_m_s2``
        must be given.

    Raises
    ------
    ValueError
        If a quantity is not a finite real number, is out of range, or the base excitation
        is not given exactly once. The message names the field, the value and what is allowed.
    """

    length_m: float = field(metadata=_LENGTH)
    width_m: float = field(metadata=_LENGTH)
    thickness_m: float = field(metadata=_LENGTH)
    density_kg_m3: float = field(metadata=_DENSITY)
    youngs_modulus_pa: float = field(metadata=_MODULUS)
    outer_mass_kg: float = field(metadata=_MASS)
    spring_n_m: float = field(metadata=_SPRING)
    gap_m: float | None = field(default=None, metadata={**_GAP, **_OPT})
    damping_ratio: float = field(default=0.0, metadata=_DAMPING)
    # The optional gaps stay None when omitted instead of being filled with gap_m, so that
    # dataclasses.replace(cell, gap_m=...) still moves both gaps.
    gap1_m: float | None = field(default=None, metadata={**_GAP, **_OPT})
    gap2_m: float | None = field(default=None, metadata={**_GAP, **_OPT})
    base_amplitude_m: float | None = field(default=None, metadata={**_AMPLITUDE, **_OPT})
    base_acceleration_m_s2: float | None = field(default=None, metadata={**_ACCELERATION, **_OPT})

    def __post_init__(self) -> None:
        """Validate every field and normalise numbers to built-in ``float``."""
        # Normalising (e.g. numpy scalars, ints) keeps repr/equality/hashing predictable.
        check_fields(self)
        if self.gap_m is None and (self.gap1_m is None or self.gap2_m is None):
            raise ValueError(
                "gap_m must be given, or both gap1_m and gap2_m, got "
                f"gap1_m={self.gap1_m!r}, gap2_m={self.gap2_m!r}"
            )
        amplitude, acceleration = self.base_amplitude_m, self.base_acceleration_m_s2
        if (amplitude is None) == (acceleration is None):
            raise ValueError(
                "exactly one of base_amplitude_m and base_acceleration_m_s2 must be given, "
                f"got base_amplitude_m={amplitude!r}, base_acceleration_m_s2={acceleration!r}"
            )

    # ----------------------------------------------------------------------------------
    # Constructors

    @classmethod
    def from_added_mass(
        cls, *, body_mass_kg: float, added_mass_kg: float, **fields: Any
    ) -> PhysicalCell:
        """Build a cell whose outer mass is a body plus rigidly attached extra mass.

        Parameters
        ----------
        body_mass_kg : float
            Mass of the outer body itself, > 0.
        added_mass_kg : float
            Mass rigidly attached to it (e.g. an accelerometer), >= 0.
        **fields
            Every other :class:`PhysicalCell` field, by keyword; ``outer_mass_kg`` must not
            be among them.

        Returns
        -------
        PhysicalCell
            With ``outer_mass_kg = body_mass_kg + added_mass_kg``.

        Raises
        ------
        ValueError
            If a mass is out of range or ``outer_mass_kg`` is also passed.
        """
        if "outer_mass_kg" in fields:
            raise ValueError(
                "outer_mass_kg must not be given to from_added_mass, got "
                f"{fields['outer_mass_kg']!r}; pass body_mass_kg and added_mass_kg instead"
            )
        body = positive("body_mass_kg", body_mass_kg)
        added = nonnegative("added_mass_kg", added_mass_kg)
        return cls(outer_mass_kg=body + added, **fields)

    @classmethod
    def table1(
        cls,
        *,
        damping_ratio: float,
        base_amplitude_m: float | None = None,
        base_acceleration_m_s2: float | None = None,
    ) -> PhysicalCell:
        """Return the paper's Table 1 cell.

        PLA beam 0.15 × 0.01 × 0.0025 m, ρ = 1250 kg/m³, E = 4.583·10⁷ Pa, gap 1 mm on each
        side, outer mass 12.67 g plus a 4 g accelerometer, spring 350 N/m.

        Parameters
        ----------
        damping_ratio : float
            ``ξ >= 0``. Required: the paper does not report it (docs/model.md §8).
        base_amplitude_m, base_acceleration_m_s2 : float or None
            The base excitation, exactly one of them. Not defaulted for the same reason.

        Returns
        -------
        PhysicalCell

        Raises
        ------
        ValueError
            If the damping ratio or excitation is out of range, or the excitation is given
            neither or both ways.
        """
        return cls.from_added_mass(
            length_m=0.15,
            width_m=0.01,
            thickness_m=0.0025,
            density_kg_m3=1250.0,
            youngs_modulus_pa=4.583e7,
            # The paper says the accelerometer "is included in the outer mass"; docs/model.md §8
            # fixes m_o = 12.67 g + 4 g = 16.67 g.
            body_mass_kg=12.67e-3,
            added_mass_kg=4.0e-3,
            spring_n_m=350.0,
            gap_m=1.0e-3,
            damping_ratio=damping_ratio,
            base_amplitude_m=base_amplitude_m,
            base_acceleration_m_s2=base_acceleration_m_s2,
        )

    # ----------------------------------------------------------------------------------
    # Derived physical quantities

    @property
    def area_m2(self) -> float:
        """Cross-section area ``A = b h`` (m²)."""
        return self.width_m * self.thickness_m

    @property
    def second_moment_m4(self) -> float:
        """Second moment of area ``I = b h³ / 12`` (m⁴) for bending through the thickness."""
        return self.width_m * self.thickness_m**3 / 12.0

    @property
    def EI(self) -> float:  # noqa: N802 - the conventional symbol reads best here
        """Bending stiffness ``EI`` (N·m²)."""
        return self.youngs_modulus_pa * self.second_moment_m4

    @property
    def rho_A_L(self) -> float:  # noqa: N802
        """Beam mass ``ρAL`` (kg)."""
        return self.density_kg_m3 * self.area_m2 * self.length_m

    @property
    def omega_m(self) -> float:
        """Natural angular frequency of the outer mass on its spring, ``√(k/m_o)`` (rad/s)."""
        return math.sqrt(self.spring_n_m / self.outer_mass_kg)

    @property
    def f_m_hz(self) -> float:
        """Natural frequency of the outer mass on its spring, ``ω_m / 2π`` (Hz)."""
        return self.omega_m / (2.0 * math.pi)

    @property
    def theta(self) -> float:
        """Mass ratio ``θ = ρAL / m_o``."""
        return self.rho_A_L / self.outer_mass_kg

    @property
    def sigma(self) -> float:
        """Beam stiffness parameter ``σ = EI / (ρA L⁴ ω_m²)`` (with ``ω_b = ω_m``)."""
        return self.EI / (self.rho_A_L * self.length_m**3 * self.omega_m**2)

    @property
    def gaps_m(self) -> tuple[float, float]:
        """Resolved clearances ``(g1, g2)`` to stop 1 and stop 2 (m)."""
        g1 = self.gap_m if self.gap1_m is None else self.gap1_m
        g2 = self.gap_m if self.gap2_m is None else self.gap2_m
        assert g1 is not None and g2 is not None  # __post_init__ guarantees both
        return (g1, g2)

    def beam_mode_frequencies_hz(self, n: int) -> NDArray[np.float64]:
        """Return the first ``n`` clamped–free natural frequencies of the bare beam (Hz).

        ``f_i = β_i² √(EI / (ρA L⁴)) / 2π``: the beam clamped to a fixed support, i.e. the
        outer mass held still. Non-dimensionally this is ``ω̃_i = β_i² √σ`` times ``ω_m``.

        Parameters
        ----------
        n : int
            Number of modes, ``>= 1``.

        Returns
        -------
        numpy.ndarray
            Shape ``(n,)``, increasing.

        Raises
        ------
        ValueError
            If ``n`` is not an integer ``>= 1``.
        """
        scale = math.sqrt(self.EI / (self.rho_A_L * self.length_m**3))
        return betas(n) ** 2 * scale / (2.0 * math.pi)

    # ----------------------------------------------------------------------------------
    # Frequency conversion and the non-dimensional model

    def hz_to_gamma_r(self, frequency_hz: float) -> float:
        """Return the non-dimensional excitation frequency ``γ_r = 2πf / ω_m``.

        Parameters
        ----------
        frequency_hz : float
            Excitation frequency ``f`` (Hz), finite and > 0.

        Returns
        -------
        float

        Raises
        ------
        ValueError
            If ``frequency_hz`` is not finite and > 0.
        """
        f = check_field("frequency_hz", frequency_hz, FREQUENCY_HZ)
        return 2.0 * math.pi * f / self.omega_m

    def gamma_r_to_hz(self, gamma_r: float) -> float:
        """Return the excitation frequency ``f = γ_r ω_m / 2π`` (Hz); inverse of
        :meth:`hz_to_gamma_r`.

        Parameters
        ----------
        gamma_r : float
            Non-dimensional excitation frequency, finite and > 0.

        Returns
        -------
        float

        Raises
        ------
        ValueError
            If ``gamma_r`` is not finite and > 0.
        """
        g = positive("gamma_r", gamma_r)
        return g * self.omega_m / (2.0 * math.pi)

    def base_amplitude_at(self, frequency_hz: float) -> float:
        """Return the base displacement amplitude ``U_g`` (m) at an excitation frequency.

        Parameters
        ----------
        frequency_hz : float
            Excitation frequency (Hz), finite and > 0.

        Returns
        -------
        float
            ``base_amplitude_m`` if the cell was given one, else ``a / Ω²`` with
            ``Ω = 2πf`` (a harmonic displacement ``U sin Ωt`` has acceleration amplitude
            ``U Ω²``).

        Raises
        ------
        ValueError
            If ``frequency_hz`` is not finite and > 0.
        """
        f = check_field("frequency_hz", frequency_hz, FREQUENCY_HZ)
        if self.base_amplitude_m is not None:
            return self.base_amplitude_m
        assert self.base_acceleration_m_s2 is not None  # guaranteed by __post_init__
        omega = 2.0 * math.pi * f
        return self.base_acceleration_m_s2 / omega**2

    def length_scale_m(self, frequency_hz: float) -> float:
        """Return the model's length unit ``B = U_g / (θ γ_s) = U_g / θ`` (m) at a frequency.

        Non-dimensional displacements (``s``, ``w_tip``, the gaps) are in units of ``B``;
        multiply by it to get metres.

        Parameters
        ----------
        frequency_hz : float
            Excitation frequency (Hz), finite and > 0.

        Returns
        -------
        float

        Raises
        ------
        ValueError
            If ``frequency_hz`` is not finite and > 0.
        """
        return self.base_amplitude_at(frequency_hz) / self.theta

    def to_model(self, frequency_hz: float) -> dict[str, float]:
        """Return the non-dimensional model parameters at an excitation frequency.

        Parameters
        ----------
        frequency_hz : float
            Excitation frequency ``f`` (Hz), finite and > 0.

        Returns
        -------
        dict of str to float
            ``theta``, ``sigma``, ``gamma_s`` (always 1.0), ``gamma_r`` (``2πf/ω_m``), ``xi``,
            ``g1`` and ``g2`` (``g̃ = g/B = g θ / U_g``).

        Raises
        ------
        ValueError
            If ``frequency_hz`` is not finite and > 0.
        """
        b = self.length_scale_m(frequency_hz)
        g1, g2 = self.gaps_m
        return {
            "theta": self.theta,
            "sigma": self.sigma,
            # ω_b = ω_m by the choice of docs/model.md §8, so the beam/mass frequency ratio is 1.
            "gamma_s": 1.0,
            "gamma_r": self.hz_to_gamma_r(frequency_hz),
            "xi": self.damping_ratio,
            "g1": g1 / b,
            "g2": g2 / b,
        }


# The cell's own quantities: always given, always > 0 (the gaps and the excitation have their
# own rules: gap_m or both gap1_m and gap2_m, exactly one of the two excitations).
CELL_FIELDS: tuple[str, ...] = tuple(f.name for f in fields(PhysicalCell) if f.default is MISSING)
