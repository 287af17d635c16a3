"""The progress line of a first compilation: it counts numba's compilations and talks."""

from __future__ import annotations

import io

import numba

from worker.compile_progress import COMPILED_FUNCTIONS, compile_progress


class _Tty(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_it_counts_each_function_numba_compiles_and_names_it() -> None:
    out = io.StringIO()

    @numba.njit(cache=False)
    def inner(x: float) -> float:
        return x * 2.0

    @numba.njit(cache=False)
    def outer(x: float) -> float:
        return inner(x) + 1.0

    with compile_progress("event", out, every_s=0.0) as progress:
        assert outer(1.0) == 3.0
    assert progress.done == 2  # outer, and inner compiled for it
    lines = out.getvalue().splitlines()
    assert len(lines) == 2
    assert lines[-1].startswith("impactcell: compiling 'event': 2 of about ")
    assert f"of about {COMPILED_FUNCTIONS['event']} functions" in lines[-1]
    assert "outer" in lines[-1] or "inner" in lines[-1]


def test_on_a_terminal_it_rewrites_one_line_and_clears_it() -> None:
    out = _Tty()

    @numba.njit(cache=False)
    def f(x: float) -> float:
        return x + 1.0

    with compile_progress("euler", out, every_s=0.0):
        f(1.0)
    text = out.getvalue()
    assert "\n" not in text and text.startswith("\rimpactcell: compiling 'euler': 1 of about ")
    assert text.endswith("\r")  # cleared: the next message starts on a clean line


def test_quiet_between_reports_and_silent_without_compiling() -> None:
    out = io.StringIO()

    @numba.njit(cache=False)
    def g(x: float) -> float:
        return x - 1.0

    g(1.0)  # compiled before the block: nothing to report inside it
    with compile_progress("exponential", out, every_s=3600.0) as progress:
        g(2.0)
    assert progress.done == 0 and out.getvalue() == ""
