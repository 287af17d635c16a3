"""The event solver's measurement as differences of primitives: a period's integrals in O(modes²)
per regime segment instead of work on every sub-grid interval.

Within one regime the state's modal coefficients evolve as ``α_k(t) = α_k(t₀) e^{λ_k (t - t₀)}``
and every integrand the period rows need is a sum of exponentials of known rates:

* the first harmonics ``∫ s e^{-iθ} dt`` (θ = γ(τ - τ_k), the forcing phase): with
  ``s = Re Σ RV_k α_k``, the terms ``½ RV_k α_k e^{-iθ}`` (rate ``λ_k - iγ``) and
  ``½ conj(RV_k α_k) e^{-iθ}`` (rate ``λ̄_k - iγ``); the same for ``s_b``;
* the phase-portrait integrals ``∫ ṡ²`` and ``∫ ṡ_b ṡ``: ``Re x Re y = ½ Re(xy + x ȳ)`` makes
  them sums over pairs k ≤ l of ``Re(I α_k α_l)`` (rate ``λ_k + λ_l``) and ``Re(I α_k ᾱ_l)``
  (rate ``λ_k + λ̄_l``).

A term ``c(t)`` of rate μ integrates to ``(c(t₁) - c(t₀))/μ``: its primitive, evaluated at the
segment's two ends, so consecutive sub-grid intervals telescope and a segment costs two
evaluations (:func:`primitive`) however many intervals it spans. Where ``|μ| T`` is small the
difference would cancel (the forcing mode itself has ``λ = iγ``, so its harmonic term has rate
0; an undamped mode's ``|α|²`` term too): those terms are listed and integrated directly from
the segment's start, ``c(t₀) φ₁(μ, L)`` with ``φ₁(μ, L) = (e^{μL} - 1)/μ`` (:func:`direct`).
Both are exact integrals of the exact motion (round-off only); they replaced per-interval
harmonic tables and 4-point Gauss-Legendre rules for ``ṡ²`` and ``ṡ_b ṡ``, which cost as much
as the propagation itself in every measured period.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from worker.solvers.event.regimes import R_S, R_SB, R_SBD, R_SD
from worker.solvers.event.roots import phi1

# Terms whose rate has |μ|·T below this are integrated directly (cancellation in the
# primitive's difference grows like round-off/(|μ| T); here at most ~5e-15 of a period's value
# per segment).
DIRECT_MU_T = 0.05

# outputs of a direct term: the harmonics of s and s_b (complex, rotated by the forcing phase at
# the segment's start), ∫ṡ² and ∫ṡ_b ṡ (real parts)
OUT_HS = 0
OUT_HSB = 1
OUT_VV = 2
OUT_VB = 3
# kinds of term: α_k, ᾱ_k (harmonics), α_k α_l, α_k ᾱ_l (pairs)
T_A = 0
T_AC = 1
T_AA = 2
T_AAC = 3

# numba's fastmath flags of the event solver's small dot products and matrix-vector products
# (kernel.py too): reassociation lets LLVM vectorise them (a different summation order, never
# NaN/inf assumptions).
FAST = {"reassoc", "contract"}


@njit(cache=True, nogil=True, inline="always")
def _add(r, T2, coef, mu, k, l, kind, out, H, hrow, C, crow, dint, dcm, n):
    """One term: into the primitive's tables (coef/μ) or, for a small |μ|·T, the direct list.
    Returns the direct list's new length."""
    if (mu.real * mu.real + mu.imag * mu.imag) * T2 >= DIRECT_MU_T * DIRECT_MU_T:
        if kind <= T_AC:
            H[r, hrow, k] += coef / mu
        else:
            C[r, crow, k, l] += coef / mu
        return n
    dint[r, n, 0] = k
    dint[r, n, 1] = l
    dint[r, n, 2] = kind
    dint[r, n, 3] = out
    dcm[r, n, 0] = coef
    dcm[r, n, 1] = mu
    return n + 1


@njit(cache=True, nogil=True)
def _terms(r, lam, RV, nk, gamma, H, C, dint, dcm):
    """Sort regime r's terms (see the module's docstring); returns how many are direct."""
    T = 2.0 * math.pi / gamma
    T2 = T * T
    n = 0
    for k in range(nk):
        lk = lam[r, k]
        for o in range(2):
            row = R_S if o == 0 else R_SB
            c = 0.5 * RV[r, row, k]
            n = _add(r, T2, c, lk - 1j * gamma, k, k, T_A, o, H, 2 * o, C, 0, dint, dcm, n)
            n = _add(r, T2, c.conjugate(), lk.conjugate() - 1j * gamma, k, k, T_AC, o, H,
                     2 * o + 1, C, 0, dint, dcm, n)  # fmt: skip
    for k in range(nk):
        dk = RV[r, R_SD, k]
        bk = RV[r, R_SBD, k]
        for l in range(k, nk):
            dl = RV[r, R_SD, l]
            bl = RV[r, R_SBD, l]
            mua = lam[r, k] + lam[r, l]
            mub = lam[r, k] + lam[r, l].conjugate()
            if l == k:
                vva = 0.5 * dk * dk
                vvb = 0.5 * dk * dk.conjugate()
                vba = 0.5 * bk * dk
                vbb = 0.5 * bk * dk.conjugate()
            else:
                vva = dk * dl
                vvb = dk * dl.conjugate()
                vba = 0.5 * (bk * dl + bl * dk)
                vbb = 0.5 * (bk * dl.conjugate() + bl.conjugate() * dk)
            n = _add(r, T2, vva, mua, k, l, T_AA, OUT_VV, H, 0, C, 0, dint, dcm, n)
            n = _add(r, T2, vvb, mub, k, l, T_AAC, OUT_VV, H, 0, C, 1, dint, dcm, n)
            n = _add(r, T2, vba, mua, k, l, T_AA, OUT_VB, H, 0, C, 2, dint, dcm, n)
            n = _add(r, T2, vbb, mub, k, l, T_AAC, OUT_VB, H, 0, C, 3, dint, dcm, n)
    return n


@njit(cache=True, nogil=True)
def measure_tables(lam, RV, nk, gamma):
    """The primitive's tables of the three regimes (regime 2 is regime 1's): ``H`` (3, 4, nz)
    complex, rows α- and ᾱ-coefficients of the s harmonic, then of s_b's; ``C`` (3, 4, nz, nz)
    complex over pairs k ≤ l, rows α_kα_l and α_kᾱ_l of ∫ṡ², then of ∫ṡ_b ṡ; and the direct
    terms: ``dint`` (3, ·, 4) (k, l, kind, output), ``dcm`` (3, ·, 2) (coefficient, rate), the
    first ``nd[r]`` rows of regime r."""
    nz = lam.shape[1]
    H = np.zeros((3, 4, nz), dtype=np.complex128)
    C = np.zeros((3, 4, nz, nz), dtype=np.complex128)
    nd = np.zeros(3, dtype=np.int64)
    most = 4 * nz + 2 * nz * (nz + 1)  # every term of a regime
    dint = np.empty((3, most, 4), dtype=np.int64)
    dcm = np.empty((3, most, 2), dtype=np.complex128)
    for r in range(2):
        nd[r] = _terms(r, lam, RV, nk[r], gamma, H, C, dint, dcm)
    nd[2] = nd[1]
    H[2] = H[1]
    C[2] = C[1]
    dint[2, : nd[1]] = dint[1, : nd[1]]
    dcm[2, : nd[1]] = dcm[1, : nd[1]]
    return H, C, dint, dcm, nd


@njit(cache=True, nogil=True, fastmath=FAST)
def primitive(r, a, nk, H, C, rc, rs):
    """The primitives of regime r at modal coefficients a and forcing phase ``e^{-iθ} = rc + i
    rs``: (s harmonic re, im, s_b harmonic re, im, ∫ṡ², ∫ṡ_b ṡ). A segment's integrals are their
    difference between its ends, plus :func:`direct`."""
    zs = 0.0 + 0.0j
    zb = 0.0 + 0.0j
    vv = 0.0
    vb = 0.0
    for k in range(nk):
        ak = a[k]
        akc = ak.conjugate()
        zs += H[r, 0, k] * ak + H[r, 1, k] * akc
        zb += H[r, 2, k] * ak + H[r, 3, k] * akc
        for l in range(k, nk):
            p = ak * a[l]
            q = ak * a[l].conjugate()
            vv += (C[r, 0, k, l] * p).real + (C[r, 1, k, l] * q).real
            vb += (C[r, 2, k, l] * p).real + (C[r, 3, k, l] * q).real
    return (zs.real * rc - zs.imag * rs, zs.real * rs + zs.imag * rc,
            zb.real * rc - zb.imag * rs, zb.real * rs + zb.imag * rc, vv, vb)  # fmt: skip


@njit(cache=True, nogil=True)
def direct(r, a0, ln, rc, rs, dint, dcm, nd):
    """The directly integrated terms over a segment of length ln of regime r that starts at
    modal coefficients a0 and forcing phase ``e^{-iθ₀} = rc + i rs``: what :func:`primitive`
    leaves out, in its order."""
    zs = 0.0 + 0.0j
    zb = 0.0 + 0.0j
    vv = 0.0
    vb = 0.0
    for i in range(nd[r]):
        k = dint[r, i, 0]
        kind = dint[r, i, 2]
        if kind == T_A:
            x = a0[k]
        elif kind == T_AC:
            x = a0[k].conjugate()
        elif kind == T_AA:
            x = a0[k] * a0[dint[r, i, 1]]
        else:
            x = a0[k] * a0[dint[r, i, 1]].conjugate()
        v = dcm[r, i, 0] * x * phi1(dcm[r, i, 1], ln)
        out = dint[r, i, 3]
        if out == OUT_HS:
            zs += v
        elif out == OUT_HSB:
            zb += v
        elif out == OUT_VV:
            vv += v.real
        else:
            vb += v.real
    return (zs.real * rc - zs.imag * rs, zs.real * rs + zs.imag * rc,
            zb.real * rc - zb.imag * rs, zb.real * rs + zb.imag * rc, vv, vb)  # fmt: skip
