"""One CPU target for the numbers: the same BLAS kernels and compiled code on every x86-64 machine.

A point's last bits depend on the CPU in three ways:

* OpenBLAS (numpy's and scipy's copies: the set-up's eigen-decompositions, inverses and
  products, and numba's ``np.linalg`` inside kernels) picks its kernels by CPU when it loads;
  forcing other kernels (``Sandybridge``) on an AVX2 machine changes 59 of the point-engine
  benchmark's 120 points, 2 of them in outcome or period (``audits/cpu_targets.py``).
* numba compiles for the host CPU: its name and, separately, its feature list. Compiling for a
  ``generic`` x86-64 instead changes 55 of them, 2 in outcome or period. Naming the CPU alone is
  not enough: numba still adds the host's features (``NUMBA_CPU_FEATURES`` unset), so on an
  AVX-512 machine ``haswell`` code uses AVX-512 instructions and rounds otherwise (two worker
  tests and the nightly suite's Table 1 study end otherwise there).
* numpy dispatches its float64 ``exp``, ``log``, ``sin`` and ``cos`` to AVX-512 versions where
  the CPU has them (their own approximations, not libm's).
* OpenBLAS splits a product over its threads (one per core unless told), which sums in another
  order: on this 2-core machine the ``exponential`` method's zero-gap point (full coupling,
  θ 0.2, γ_r 0.5) confirmed its orbit after 45 periods with two threads and 21 with one, Γ
  3e-10 dB apart, and 3 of the nightly suite's 8 studies (the ``exponential`` ones) differed
  between ``--serial`` (the command's own process) and the cluster (its workers have one thread)
  at 479 of 1,196 points, 22 of them in outcome (up to 8.3 dB).

Converged linear and periodic answers agree far inside every tolerance, but a grazing or
chaotic point amplifies the difference into another outcome (transient chaos dying out or not,
coexisting orbits): the nightly suite's baselines, cut on another machine, differed from an AVX2
machine's run at 26 of 2,044 points.

:func:`pin` fixes the first three on every x86-64 CPU with AVX2 and FMA:
``OPENBLAS_CORETYPE=Haswell`` (read when OpenBLAS loads), ``NUMBA_CPU_NAME=haswell`` with
``NUMBA_CPU_FEATURES=""`` (Haswell's own features and no others; read when numba is imported)
and ``NPY_DISABLE_CPU_FEATURES`` naming numpy's AVX-512 targets (read when
numpy is imported; on a CPU without them it changes nothing); and the last on every CPU: one
BLAS thread (``OPENBLAS_NUM_THREADS``, ``OMP_NUM_THREADS``, ``MKL_NUM_THREADS``, read when the
library loads; the matrices are small, threads only contend with the other worker processes).
``worker`` calls it first thing, so every process that imports ``worker`` before numpy and numba,
and every process started from one (dask's worker processes inherit the environment), computes
with the same kernels: the ``service`` package imports ``worker`` first, and scripts that load
numpy themselves (the benchmarks, tests/conftest.py) import it before. A value already set is
the user's choice and kept. Other CPUs (aarch64,
x86-64 without AVX2) are left to the libraries.

glibc's libm (called by the compiled kernels for ``sin``, ``cos``, ``exp``) picks its own
versions by CPU too, but has none above FMA for these: every x86-64 CPU with AVX2 and FMA runs
the same ones. :func:`fingerprint` names everything above for one process, so a cluster can
refuse a worker that computes otherwise (``service/studies/runner.py``).
"""

from __future__ import annotations

import functools
import os
import platform
import re
import sys

__all__ = [
    "BLAS_CORE", "BLAS_ENV", "FEATURES_ENV", "FINGERPRINT_KEYS", "NUMBA_CPU", "NUMBA_ENV",
    "NUMPY_ENV", "NUMPY_OFF",
    "REMEDY", "THREAD_ENVS", "TargetMismatch", "blas_threads", "check_target", "compiled_for",
    "differences", "fingerprint", "kernels", "numpy_simd", "on_pinned_target", "pin", "pinnable",
    "target_label",
]  # fmt: skip

BLAS_ENV, BLAS_CORE = "OPENBLAS_CORETYPE", "Haswell"
NUMBA_ENV, NUMBA_CPU = "NUMBA_CPU_NAME", "haswell"
# What :func:`fingerprint` names, in its order.
FINGERPRINT_KEYS = (
    "numba_cpu", "blas_kernels", "blas_threads", "numpy_simd", "machine", "libc",
    "numpy_version", "scipy_version", "numba_version", "llvmlite_version",
)  # fmt: skip
# Empty: the named CPU's own features. Unset, numba adds the host's (AVX-512 where it has it).
FEATURES_ENV = "NUMBA_CPU_FEATURES"
# numpy 2's dispatch targets above AVX2 (x86-64-v3); numpy warns about names it does not know.
NUMPY_ENV, NUMPY_OFF = "NPY_DISABLE_CPU_FEATURES", "X86_V4 AVX512_ICL AVX512_SPR"
_NEEDS = frozenset({"avx2", "fma"})  # what both targets use
# The BLAS libraries' thread counts (OpenBLAS reads the first, else the second; MKL the third).
THREAD_ENVS = ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS")


def _cpu_flags() -> frozenset[str]:
    """The CPU's feature flags (Linux ``/proc/cpuinfo``; empty where it cannot be read)."""
    try:
        with open("/proc/cpuinfo", encoding="ascii", errors="replace") as f:
            for line in f:
                if line.startswith("flags"):
                    return frozenset(line.partition(":")[2].split())
    except OSError:
        pass
    return frozenset()


def pinnable(flags: frozenset[str] | None = None) -> bool:
    """Whether this CPU (or one with these ``flags``) runs the pinned targets."""
    have = _cpu_flags() if flags is None else flags
    return platform.machine().lower() in ("x86_64", "amd64") and have >= _NEEDS


def pin(flags: frozenset[str] | None = None) -> str | None:
    """Set ``OPENBLAS_CORETYPE``, ``NUMBA_CPU_NAME``, ``NUMBA_CPU_FEATURES`` and
    ``NPY_DISABLE_CPU_FEATURES`` where the CPU runs those targets, and one BLAS thread
    (``THREAD_ENVS``) on every CPU.

    Returns the OpenBLAS core type now in the environment (``None``: left to OpenBLAS). Only
    libraries loaded afterwards are affected: numpy or numba imported earlier keep their choice.
    """
    for var in THREAD_ENVS:
        os.environ.setdefault(var, "1")
    if pinnable(flags):
        os.environ.setdefault(BLAS_ENV, BLAS_CORE)
        os.environ.setdefault(NUMBA_ENV, NUMBA_CPU)
        os.environ.setdefault(FEATURES_ENV, "")
        os.environ.setdefault(NUMPY_ENV, NUMPY_OFF)
        _warn_if_too_late()
    else:
        _warn_if_too_late(targets=False)
    return os.environ.get(BLAS_ENV) or None


def _warn_if_too_late(targets: bool = True) -> None:
    """Say so when numpy or numba was loaded before the pin with another target or BLAS thread
    count: this process's numbers may then differ from the service's at grazing or chaotic
    points."""
    late = []
    wanted = []
    if targets:
        blas = kernels()
        # An empty value asks for the library's own choice: nothing to compare it with.
        if os.environ[BLAS_ENV] and blas not in (os.environ[BLAS_ENV], "unknown"):
            late.append(f"numpy's OpenBLAS runs its {blas} kernels")
        want = _target_name(os.environ[NUMBA_ENV], os.environ[FEATURES_ENV])
        target = compiled_for() if "numba" in sys.modules else want
        if os.environ[NUMBA_ENV] and target != want:
            late.append(f"numba compiles for {target}")
        wanted += [
            f"{BLAS_ENV}={os.environ[BLAS_ENV]}",
            f"{NUMBA_ENV}={os.environ[NUMBA_ENV]} with {FEATURES_ENV}={os.environ[FEATURES_ENV]!r}",
        ]
    threads = blas_threads()
    want = os.environ[THREAD_ENVS[0]]
    if threads is not None and want.isdigit() and threads != int(want):
        late.append(f"numpy's OpenBLAS runs {threads} threads")
        wanted.append(f"{THREAD_ENVS[0]}={want}")
    if late:
        import warnings

        warnings.warn(
            f"{' and '.join(late)}, not {' and '.join(wanted)} (loaded before worker): "
            "grazing or chaotic points may end otherwise than in the service; import worker "
            "first, or set these before starting Python",
            RuntimeWarning,
            stacklevel=3,
        )


def _openblas(name: str, restype: object) -> object:
    """Call OpenBLAS's ``openblas_<name>()`` in numpy's copy; None where numpy is not loaded,
    its BLAS is not OpenBLAS or cannot be asked."""
    if "numpy" not in sys.modules:
        return None
    import ctypes

    try:
        with open("/proc/self/maps", encoding="utf-8", errors="replace") as f:
            libs = sorted(set(re.findall(r"(/\S*openblas\S*\.so\S*)", f.read())))
    except OSError:
        return None
    for path in libs:
        try:
            lib = ctypes.CDLL(path)
        except OSError:
            continue
        # numpy's build (scipy-openblas64) suffixes its symbols; a plain build does not.
        for symbol in (f"scipy_openblas_{name}64_", f"openblas_{name}"):
            fn = getattr(lib, symbol, None)
            if fn is not None:
                fn.restype = restype
                return fn()
    return None


def kernels() -> str:
    """The kernels numpy's OpenBLAS runs in this process (``"Haswell"``, ``"SkylakeX"``, …).

    ``"unknown"`` where numpy is not loaded, its BLAS is not OpenBLAS or cannot be asked.
    """
    import ctypes

    name = _openblas("get_corename", ctypes.c_char_p)
    if not isinstance(name, bytes):
        return "unknown"
    return name.decode("ascii", "replace").strip() or "unknown"


def blas_threads() -> int | None:
    """The threads numpy's OpenBLAS runs in this process (None where it cannot be asked)."""
    import ctypes

    n = _openblas("get_num_threads", ctypes.c_int)
    return int(n) if isinstance(n, int) else None


def _target_name(name: str, features: str | None) -> str:
    """A numba target as one word: the CPU's name, ``+host`` where numba adds the host's
    features, ``+<list>`` where it adds others, nothing more where the name's own are used."""
    if features is None:
        return f"{name}+host"
    return f"{name}+{features.lstrip('+')}" if features else name


def compiled_for() -> str:
    """The CPU numba compiles this process's kernels for: ``"haswell"`` when pinned (its own
    features only), ``"haswell+host"`` when the host's features are added, or the host's name."""
    import llvmlite.binding as ll
    from numba.core import config

    name = str(config.CPU_NAME or ll.get_host_cpu_name())
    features = config.CPU_FEATURES
    if config.CPU_NAME is None and features is None:
        return name  # the host itself: its name says it
    return _target_name(name, None if features is None else str(features))


def numpy_simd() -> str:
    """numpy's highest enabled dispatch target in this process (``"X86_V3"`` when pinned on an
    AVX2 machine; ``"baseline"`` where none above the build's baseline runs; ``"unknown"`` where
    numpy cannot say)."""
    try:
        from numpy._core._multiarray_umath import __cpu_dispatch__, __cpu_features__
    except ImportError:
        return "unknown"
    enabled = [t for t in __cpu_dispatch__ if __cpu_features__.get(t)]
    return enabled[-1] if enabled else "baseline"


@functools.cache
def fingerprint() -> dict[str, str]:
    """What decides this process's last bits of a point: the compiled target, the BLAS kernels
    and threads, numpy's dispatch, and the versions of the libraries that compute.

    Equal fingerprints compute equal bits for the same solver version. Imports numpy and numba.
    """
    from importlib import metadata

    import numpy  # noqa: F401  (kernels() and numpy_simd() ask the loaded copy)

    def version(name: str) -> str:
        try:
            return metadata.version(name)
        except metadata.PackageNotFoundError:
            return "unknown"

    libc = platform.libc_ver()
    return {
        "numba_cpu": compiled_for(),
        "blas_kernels": kernels(),
        "blas_threads": str(blas_threads()),
        "numpy_simd": numpy_simd(),
        "machine": platform.machine().lower(),
        "libc": " ".join(libc) if libc[0] else "unknown",
        **{f"{lib}_version": version(lib) for lib in ("numpy", "scipy", "numba", "llvmlite")},
    }


def on_pinned_target() -> bool:
    """Whether this process computes with the pinned targets (the same bits as every x86-64
    machine with AVX2 and FMA, for the same library versions)."""
    fp = fingerprint()
    off = set(NUMPY_OFF.split())
    return (
        fp["numba_cpu"] == NUMBA_CPU and fp["blas_kernels"] == BLAS_CORE
        and fp["numpy_simd"] not in off
    )  # fmt: skip


def target_label() -> str:
    """This process's compiled target, BLAS kernels and numpy dispatch as one word."""
    fp = fingerprint()
    return f"{fp['machine']}/{fp['numba_cpu']}/{fp['blas_kernels']}/{fp['numpy_simd']}"


# How to start a worker so that it computes like the service (docker-compose.yml does this).
REMEDY = (
    "start each worker so that it imports worker before numpy loads: "
    "`dask worker --preload-nanny worker SCHEDULER` (the nanny pins the environment its worker "
    "starts with), with the service's library versions"
)


class TargetMismatch(RuntimeError):
    """A process computes otherwise than the one that asked it to (another CPU target or
    library stack): its points would differ in their last bits, so it computes none."""


def differences(expected: dict[str, str], actual: dict[str, str]) -> list[str]:
    """What ``actual`` (a :func:`fingerprint`) has otherwise than ``expected``, one phrase a
    field: ``"numba_cpu haswell+host, not haswell"``."""
    return [
        f"{key} {actual.get(key, 'missing')}, not {want}"
        for key, want in expected.items()
        if actual.get(key) != want
    ]


def check_target(expected: dict[str, str] | None, who: str = "this worker") -> None:
    """Raise :class:`TargetMismatch` naming every difference where this process's
    :func:`fingerprint` is not ``expected`` (``None``: nothing to check)."""
    if not expected:
        return
    diff = differences(expected, fingerprint())
    if diff:
        raise TargetMismatch(
            f"{who} computes otherwise than the service: {'; '.join(diff)}; {REMEDY}"
        )
