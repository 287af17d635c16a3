"""Smoke tests of the benchmark scripts (tiny settings; the real runs are not tests)."""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_work_precision_quick_runs(tmp_path: Path) -> None:
    path = ROOT / "benchmarks" / "work_precision.py"
    spec = importlib.util.spec_from_file_location("work_precision_smoke", path)
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod  # dataclasses look their module up while the file runs
    try:
        spec.loader.exec_module(mod)
        assert mod.main(["--quick", "--points", "1", "--no-plot", "--out", str(tmp_path)]) == 0
    finally:
        sys.modules.pop(spec.name, None)
    md = (tmp_path / "work_precision.md").read_text()
    assert "## Targets" in md and "| exponential | 2048 (default) |" in md
    rows = (tmp_path / "work_precision.csv").read_text().splitlines()
    assert rows[0].startswith("family,setting,subset,")
    assert len(rows) > 5
