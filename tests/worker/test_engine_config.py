"""The engine's tuning constants live in one place (worker/solvers/engine/config.py), each with
what it trades and the tests that pin it (checked by ``audits/config_pins.py``)."""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

from audits.config_pins import CONFIG, constants, variants
from worker.solvers.engine import config as cfg

ROOT = Path(__file__).resolve().parents[2]
ENGINE = CONFIG.parent


def _blocks() -> dict[str, str]:
    """Each constant's comment block: the comments right above it, shared by constants assigned
    one after the other."""
    out: dict[str, str] = {}
    comment: list[str] = []
    after_assign = False
    for line in CONFIG.read_text().splitlines():
        if line.startswith("#"):
            if after_assign or line.startswith("# ---"):
                comment = []
            after_assign = False
            comment.append(line)
        elif m := re.match(r"^([A-Z_]+) = ", line):
            out[m.group(1)] = "\n".join(comment)
            after_assign = True
    return out


def test_every_constant_says_what_it_trades_and_names_existing_pins() -> None:
    blocks = _blocks()
    numbers = constants()
    assert len(numbers) >= 30  # the parser sees them all (a broken parser would pass below)
    for name, (_, pins) in numbers.items():
        assert "Trades:" in blocks[name], f"{name}: no 'Trades:' line"
        assert pins, f"{name}: no 'Pinned by:' line"
        for pin in pins:
            path, _, test = pin.partition("::")
            file = ROOT / path
            assert file.is_file(), f"{name}: pin {pin}: no such file"
            assert re.search(rf"^def {re.escape(test)}\(", file.read_text(), re.M), (
                f"{name}: pin {pin}: no such test"
            )


def test_the_engine_defines_no_tuning_constant_outside_config() -> None:
    """One place: no other engine module assigns a module-level number in CAPITALS."""
    for path in ENGINE.glob("*.py"):
        if path == CONFIG:
            continue
        for node in ast.parse(path.read_text()).body:
            if isinstance(node, ast.Assign) and isinstance(node.value, ast.Constant):
                names = [getattr(t, "id", "") for t in node.targets]
                numeric = isinstance(node.value.value, (int, float))
                bad = [n for n in names if n.isupper() and numeric]
                assert not bad, f"{path.name}: {bad} belongs in config.py"


def test_history_holds_every_shrinking_test() -> None:
    from worker.solvers import measure as ms

    assert cfg.HISTORY == (cfg.SHRINK_RETURNS + 2) * ms.MAX_PERIOD
    assert cfg.RECENT <= cfg.HISTORY


@pytest.mark.parametrize(("value", "expected"), [(4, [2, 8]), (1, [2]), (0.25, [0.125, 0.5])])
def test_audit_variants_always_move_the_value(value: float, expected: list[float]) -> None:
    assert variants(value) == expected
