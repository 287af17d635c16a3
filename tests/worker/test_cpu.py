"""The CPU target is pinned (worker/cpu.py): where, to what, and that it takes effect."""

from __future__ import annotations

import os
import platform
import subprocess
import sys

import pytest

from worker import cpu

CAN_PIN = cpu.pinnable()
PINS = (cpu.BLAS_ENV, cpu.NUMBA_ENV, cpu.FEATURES_ENV, cpu.NUMPY_ENV)


def _fresh_env() -> dict[str, str]:
    """This process's environment without the pin: a child must pin itself."""
    return {k: v for k, v in os.environ.items() if k not in PINS}


@pytest.fixture
def unpinned(monkeypatch: pytest.MonkeyPatch) -> None:
    for var in PINS:
        monkeypatch.delenv(var, raising=False)


@pytest.mark.usefixtures("unpinned")
def test_pins_haswell_only_where_the_cpu_runs_it(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(platform, "machine", lambda: "x86_64")
    assert cpu.pin(frozenset({"sse2", "avx"})) is None  # no AVX2/FMA: left to the libraries
    assert not any(v in os.environ for v in PINS)
    assert cpu.pin(frozenset({"avx", "avx2", "fma", "avx512f"})) == "Haswell"
    assert (os.environ[cpu.BLAS_ENV], os.environ[cpu.NUMBA_ENV]) == ("Haswell", "haswell")
    assert os.environ[cpu.FEATURES_ENV] == ""  # Haswell's own features, never the host's
    assert os.environ[cpu.NUMPY_ENV] == "X86_V4 AVX512_ICL AVX512_SPR"


@pytest.mark.usefixtures("unpinned")
def test_other_architectures_are_left_alone(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(platform, "machine", lambda: "aarch64")
    assert cpu.pin(frozenset({"avx2", "fma"})) is None
    assert not any(v in os.environ for v in PINS)


@pytest.mark.usefixtures("unpinned")
def test_a_target_already_set_is_the_users_choice(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(platform, "machine", lambda: "x86_64")
    monkeypatch.setenv(cpu.BLAS_ENV, "Sandybridge")
    monkeypatch.setenv(cpu.NUMBA_ENV, "generic")
    # numpy and numba are loaded here with other targets than these: said, naming both.
    with pytest.warns(RuntimeWarning, match="OPENBLAS_CORETYPE=Sandybridge and NUMBA_CPU_NAME"):
        assert cpu.pin(frozenset({"avx2", "fma"})) == "Sandybridge"
    assert (os.environ[cpu.BLAS_ENV], os.environ[cpu.NUMBA_ENV]) == ("Sandybridge", "generic")


@pytest.mark.slow  # a new Python process
def test_a_fresh_process_that_imports_the_worker_first_runs_the_pinned_targets() -> None:
    env = _fresh_env()
    code = (
        "import worker, numpy; from worker.cpu import compiled_for, kernels; "
        "from numpy._core._multiarray_umath import __cpu_features__ as f; "
        "print(kernels(), compiled_for(), int(f['X86_V4']))"
    )
    out = subprocess.run(
        [sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=120
    )
    assert out.returncode == 0, out.stderr
    blas, numba_cpu, v4 = out.stdout.split()
    if CAN_PIN:  # numpy's AVX-512 versions off too, where the CPU has them
        assert (blas, numba_cpu, v4) == ("Haswell", "haswell", "0")
    else:  # the libraries' own choice, still named
        assert blas and numba_cpu


@pytest.mark.usefixtures("unpinned")
def test_one_blas_thread_on_every_cpu_unless_the_user_set_another(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setattr(platform, "machine", lambda: "aarch64")  # no target pinned, threads are
    for var in cpu.THREAD_ENVS:
        monkeypatch.delenv(var, raising=False)
    cpu.pin(frozenset())
    assert [os.environ[v] for v in cpu.THREAD_ENVS] == ["1", "1", "1"]
    monkeypatch.setenv("OPENBLAS_NUM_THREADS", "4")
    # this process's OpenBLAS (loaded by conftest with one thread) is not what was asked: said
    with pytest.warns(RuntimeWarning, match="OpenBLAS runs 1 threads, not OPENBLAS_NUM_THREADS=4"):
        cpu.pin(frozenset())
    assert os.environ["OPENBLAS_NUM_THREADS"] == "4"


def _threads_unset() -> dict[str, str]:
    return {k: v for k, v in _fresh_env().items() if k not in cpu.THREAD_ENVS}


_POINT = (
    "import worker; from worker.model import CellParams; "
    "from worker.simulate import SolverSettings, simulate_point; "
    "p = CellParams(coupling='full', modes=5, xi=0.05, g1=0.0, g2=0.0, theta=0.2, sigma=0.05, "
    "gamma_s=1.0, gamma_r=0.5); "
    "r = simulate_point(p, SolverSettings(method='exponential')); "
    "from worker.cpu import blas_threads; "
    "print(blas_threads(), repr(r.transmittance_db), r.periods)"
)


@pytest.mark.slow  # new Python processes
def test_a_point_is_the_same_in_any_process_that_imports_the_worker_first() -> None:
    # The `exponential` method's zero-gap point sums its products in another order with two
    # BLAS threads: 45 periods to its orbit instead of 21, Γ 3e-10 dB apart. A process started
    # without any thread setting (a serial run, `impactcell point`, a notebook) computes what a
    # cluster worker (one thread) does, and what this test process (conftest: one thread) does.
    from worker.model import CellParams
    from worker.simulate import SolverSettings, simulate_point

    out = subprocess.run(
        [sys.executable, "-c", _POINT], env=_threads_unset(), capture_output=True, text=True,
        timeout=600,
    )  # fmt: skip
    assert out.returncode == 0, out.stderr
    threads, gamma, periods = out.stdout.split()
    p = CellParams(coupling="full", modes=5, xi=0.05, g1=0.0, g2=0.0, theta=0.2, sigma=0.05,
                   gamma_s=1.0, gamma_r=0.5)  # fmt: skip
    here = simulate_point(p, SolverSettings(method="exponential"))
    assert threads == "1"
    assert (float(gamma), int(periods)) == (here.transmittance_db, here.periods)


@pytest.mark.slow  # a new Python process
def test_a_process_that_loaded_numpy_with_more_threads_is_told() -> None:
    out = subprocess.run(
        [sys.executable, "-c", "import numpy, worker"], env=_threads_unset(),
        capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert out.returncode == 0, out.stderr
    if (os.cpu_count() or 1) > 1:  # OpenBLAS then starts one thread per core
        assert "OpenBLAS runs" in out.stderr and "OPENBLAS_NUM_THREADS=1" in out.stderr


def test_this_process_is_pinned_by_conftest() -> None:
    # conftest imports ``worker`` before numpy and numba: the test process itself is pinned.
    if CAN_PIN:
        assert (cpu.kernels(), cpu.compiled_for()) == ("Haswell", "haswell")
    else:
        assert cpu.kernels() and cpu.compiled_for()


@pytest.mark.slow  # a new Python process
def test_a_process_that_loaded_numba_first_is_told() -> None:
    env = _fresh_env()
    out = subprocess.run(
        [sys.executable, "-c", "import numba, worker"],
        env=env, capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert out.returncode == 0, out.stderr
    if CAN_PIN:  # numba chose the host before the pin: the warning names what and the remedy
        assert "RuntimeWarning" in out.stderr and "numba compiles for" in out.stderr
        assert "import worker first" in out.stderr and "NUMBA_CPU_NAME=haswell" in out.stderr
    else:
        assert "RuntimeWarning" not in out.stderr


# Loaded in a fresh process: whether numpy was already loaded when the pin ran.
_ORDER = """
import importlib.abc, sys
class Watch(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path, target=None):
        if name == "worker.cpu":
            print("numpy loaded before the pin:", "numpy" in sys.modules)
sys.meta_path.insert(0, Watch())
import {module}
"""


@pytest.mark.slow  # a new Python process each, importing the service
@pytest.mark.parametrize(
    "module", ["service.api.app", "service.regression.run", "service.client", "service.cli"]
)
def test_every_way_into_the_service_pins_before_numpy_loads(module: str) -> None:
    # The service package imports worker first: an API app under any server, the runner or the
    # nightly run used as a library, the client all compute with the pinned targets.
    out = subprocess.run(
        [sys.executable, "-c", _ORDER.format(module=module)],
        env=_fresh_env(), capture_output=True, text=True, timeout=120,
    )  # fmt: skip
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "numpy loaded before the pin: False"


def test_the_fingerprint_names_the_pinned_target_here() -> None:
    fp = cpu.fingerprint()
    assert tuple(fp) == cpu.FINGERPRINT_KEYS
    assert all(isinstance(v, str) and v for v in fp.values())
    assert fp["blas_threads"] == "1"
    if CAN_PIN:  # no AVX-512 anywhere, whatever this CPU has
        assert (fp["numba_cpu"], fp["blas_kernels"], fp["numpy_simd"]) == (
            "haswell",
            "Haswell",
            "X86_V3",
        )


def test_a_target_name_says_whose_features_numba_adds() -> None:
    assert cpu._target_name("haswell", "") == "haswell"
    assert cpu._target_name("haswell", None) == "haswell+host"
    assert cpu._target_name("haswell", "+avx512f") == "haswell+avx512f"


def test_a_worker_with_another_fingerprint_is_refused_naming_each_difference() -> None:
    mine = cpu.fingerprint()
    cpu.check_target(dict(mine))  # the same: nothing said
    cpu.check_target(None)
    other = {**mine, "numba_cpu": "haswell+host", "numpy_version": "0.0"}
    assert cpu.differences(other, mine) == [
        f"numba_cpu {mine['numba_cpu']}, not haswell+host",
        f"numpy_version {mine['numpy_version']}, not 0.0",
    ]
    with pytest.raises(cpu.TargetMismatch, match="numba_cpu .* not haswell\\+host.*preload-nanny"):
        cpu.check_target(other)


def test_numba_compiles_for_the_pinned_cpu_with_its_own_features_only() -> None:
    # What numba hands LLVM in this (conftest-pinned) process: unset, the features would be the
    # host's (AVX-512 on such a machine), whatever the CPU's name.
    from numba import njit

    @njit
    def twice(x: float) -> float:
        return 2.0 * x

    assert twice(1.5) == 3.0
    codegen = twice.targetctx.codegen()
    if CAN_PIN:
        assert (codegen._get_host_cpu_name(), codegen._tm_features) == (cpu.NUMBA_CPU, "")


# Compiles the event kernel afresh (the cache's code cannot be disassembled), then reads it.
_ASM = """
import re, worker
from worker.simulate import warm_up
from worker.solvers.event.kernel import event_kernel
warm_up("event", quiet=True)
asm = "".join(event_kernel.inspect_asm(s) for s in event_kernel.signatures)
print(len(asm), len(re.findall(r"%zmm\\d|%k[1-7]\\b", asm)))
"""


@pytest.mark.slow  # a new Python process compiling the event kernel (~1 min)
@pytest.mark.skipif(not CAN_PIN, reason="the pin applies to x86-64 CPUs with AVX2 and FMA")
def test_the_compiled_event_kernel_uses_no_avx512_whatever_this_cpu_has(tmp_path) -> None:
    # Another CPU's code path, seen from this one: the machine code names no AVX-512 register
    # (zmm, or the mask registers k1-k7). Compiled with the host's features on an AVX-512
    # machine (NUMBA_CPU_FEATURES unset), the same kernel names them thousands of times.
    env = {**_fresh_env(), "NUMBA_CACHE_DIR": str(tmp_path)}
    out = subprocess.run(
        [sys.executable, "-c", _ASM], env=env, capture_output=True, text=True, timeout=900
    )
    assert out.returncode == 0, out.stderr
    size, avx512 = map(int, out.stdout.split())
    assert size > 100_000  # the kernel's code was read, not an empty text
    assert avx512 == 0
