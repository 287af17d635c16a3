"""Which tests pin each tuning constant of the point engine (``worker/solvers/engine/config.py``).

    python audits/config_pins.py [--only NAME,...] [--off] [--discover]
                                 [--tests "tests/worker -m 'not slow'"] [--out audits/results]

For every constant whose value is a number literal, two variants, half and double (an integer
at least 1; a count that would not change is moved by one), and a third where the constant has
an ``Off:`` line: the value that turns its rule off. Each variant runs in a fresh pytest
(``python -m pytest -n 2``) with the constant set for the whole session by the plugin in this
file (``IMPACTCELL_CONFIG_OVERRIDE=NAME=VALUE``; ``config.HISTORY`` follows
``SHRINK_RETURNS``). The engine reads ``cfg.NAME`` at call time and passes it to its compiled
helpers, so nothing is recompiled.

Default: run each constant's own ``Pinned by:`` tests and report whether at least one variant
makes one of them fail (the pins hold the value from at least one side, or hold the rule).
``--off``: only the ``Off:`` variants (a rule no test needs even when off is a candidate to
drop). ``--discover``: run the ``--tests`` selection instead and list every test that fails
under each variant (what could pin a constant that has none). Writes ``config_pins*.md``.
Exit 1 (default mode) when the pins of a constant hold nothing.
"""

from __future__ import annotations

import argparse
import ast
import os
import re
import shlex
import subprocess
import sys
import tempfile
import time
import xml.etree.ElementTree as ET
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
CONFIG = ROOT / "worker" / "solvers" / "engine" / "config.py"
ENV = "IMPACTCELL_CONFIG_OVERRIDE"


def comment_blocks(path: Path = CONFIG) -> dict[str, tuple[str, list[str]]]:
    """Every module-level constant's value text and the comment lines right above it;
    constants assigned one after the other share the block above the first."""
    out: dict[str, tuple[str, list[str]]] = {}
    block: list[str] = []
    after_assign = False
    for line in path.read_text().splitlines():
        if line.startswith("#"):
            if after_assign or line.startswith("# ---"):
                block, after_assign = [], False
            block.append(line)
        elif m := re.match(r"^([A-Z_]+) = (.+)$", line):
            out[m.group(1)] = (m.group(2), block)
            after_assign = True
    return out


def constants(path: Path = CONFIG) -> dict[str, tuple[float | int, list[str]]]:
    """Every module-level constant with a number literal value, and its pins as pytest node ids
    (``module::test`` lines under ``# Pinned by:``, modules of ``tests/worker/``)."""
    out: dict[str, tuple[float | int, list[str]]] = {}
    for name, (text, block) in comment_blocks(path).items():
        try:
            value = ast.literal_eval(text.split("  #")[0].strip())
        except (ValueError, SyntaxError):
            continue  # derived from others: not moved on its own
        if not isinstance(value, (int, float)) or isinstance(value, bool):
            continue
        pins: list[str] = []
        if "# Pinned by:" in block:
            for line in block[block.index("# Pinned by:") + 1 :]:
                m = re.match(r"^#\s+(\w+)::(\w+)$", line)
                if not m:
                    break
                pins.append(f"tests/worker/{m.group(1)}.py::{m.group(2)}")
        out[name] = (value, pins)
    return out


def offs(path: Path = CONFIG) -> dict[str, float | int]:
    """The value that switches each rule off, from the ``# Off: NAME = VALUE`` lines."""
    found = re.findall(r"^# Off: ([A-Z_]+) = (\S+)$", path.read_text(), re.M)
    return {name: _number(value) for name, value in found}


def _number(text: str) -> float | int:
    """A Python number literal, or ``inf``."""
    return float(text) if text in ("inf", "-inf") else ast.literal_eval(text)


def variants(value: float | int) -> list[float | int]:
    """Half and double; integers stay integers (at least 1) and always move."""
    if isinstance(value, int):
        return sorted({max(1, value // 2) if value > 1 else 2, 2 * value} - {value})
    return [value / 2.0, value * 2.0]


def run(tests: list[str], name: str, value: float | int) -> tuple[set[str], int, float]:
    """Failing test ids, the tests run and the seconds, with ``name`` set to ``value``."""
    with tempfile.TemporaryDirectory() as tmp:
        xml = Path(tmp) / "junit.xml"
        env = dict(os.environ, **{ENV: f"{name}={value!r}"})
        cmd = [sys.executable, "-m", "pytest", "-q", "-n", "2", "-p", "no:cacheprovider",
               "-p", "audits.config_pins", f"--junitxml={xml}", *tests]  # fmt: skip
        t = time.perf_counter()
        subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True)
        dt = time.perf_counter() - t
        failed: set[str] = set()
        total = 0
        if xml.exists():
            for case in ET.parse(xml).iter("testcase"):
                total += 1
                if case.find("failure") is not None or case.find("error") is not None:
                    path = case.get("classname", "").replace(".", "/") + ".py"
                    failed.add(f"{path}::{case.get('name')}")
        return failed, total, dt


def pytest_configure(config: object) -> None:
    """Pytest plugin hook: apply ``IMPACTCELL_CONFIG_OVERRIDE`` for the whole session."""
    given = os.environ.get(ENV)
    if not given:
        return
    from worker.solvers import measure as ms
    from worker.solvers.engine import config as cfg

    name, _, value = given.partition("=")
    setattr(cfg, name, _number(value))
    if name == "SHRINK_RETURNS":
        cfg.HISTORY = (cfg.SHRINK_RETURNS + 2) * ms.MAX_PERIOD


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", default="", help="constants to check, comma-separated")
    ap.add_argument("--discover", action="store_true",
                    help="run --tests and list every failing test per variant")  # fmt: skip
    ap.add_argument("--off", action="store_true",
                    help="one variant per constant: the value that turns its rule off")  # fmt: skip
    ap.add_argument("--tests", default="tests/worker -m 'not slow'")
    ap.add_argument("--out", type=Path, default=Path(__file__).parent / "results")
    args = ap.parse_args(argv)
    found = constants()
    off = offs()
    only = [n for n in args.only.split(",") if n]
    unknown = [n for n in only if n not in found]
    if unknown:
        ap.error(f"--only: not a number constant of config.py: {', '.join(unknown)}")
    lines = [
        "# Which tests pin the engine's tuning constants",
        "",
        f"`python audits/config_pins.py{' --discover' if args.discover else ''}"
        f"{' --only ' + args.only if only else ''}`",
        "",
        "| constant | value | variant | tests run | failing | seconds |",
        "|---|---|---|---|---|---|",
    ]
    loose: list[str] = []
    for name, (value, pins) in found.items():
        if only and name not in only:
            continue
        tests = shlex.split(args.tests) if args.discover else pins
        if not tests:
            loose.append(name)
            lines.append(f"| {name} | {value!r} | – | no pin named | – | – |")
            continue
        held = False
        own_off = [off[name]] if name in off else []
        chosen = own_off if args.off else variants(value) + own_off
        for v in chosen:
            failed, total, dt = run(tests, name, v)
            held |= bool(failed)
            shown = ", ".join(sorted(f.split("::")[-1] for f in failed)) or "none"
            lines.append(f"| {name} | {value!r} | {v!r} | {total} | {shown} | {dt:.0f} |")
            print(lines[-1], flush=True)
        if not held:
            loose.append(name)
    lines += ["", f"Constants no variant of which fails a test run: {', '.join(loose) or 'none'}."]
    args.out.mkdir(parents=True, exist_ok=True)
    name = "config_pins" + ("_discover" if args.discover else "") + ("_off" if args.off else "")
    name += ".md"
    (args.out / name).write_text("\n".join(lines) + "\n")
    print(lines[-1])
    return 1 if loose and not (args.discover or args.off) else 0


if __name__ == "__main__":
    sys.exit(main())
