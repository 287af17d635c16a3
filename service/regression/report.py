"""The nightly report: a summary, every moved point and failed check, as JSON and markdown."""

from __future__ import annotations

import os
import re
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from service.regression.compare import StudyComparison
from service.studies.chunks import atomic_write
from service.studies.dataset import json_text
from service.studies.variables import OUTCOMES

__all__ = ["NightlyReport", "map_text"]


def _fmt(x: Any, digits: int = 9) -> str:
    if x is None:
        return "missing"
    if isinstance(x, float):
        return f"{x:.{digits}g}"
    return str(x)


def _coords_text(c: Mapping[str, Any]) -> str:
    return ", ".join(f"{k}={_fmt(v, 8)}" for k, v in c.items())


@dataclass
class NightlyReport:
    """What a nightly run found, study by study."""

    studies: list[StudyComparison]
    suite: str
    baselines: str
    mode: str  # "embedded" or the service URL
    update_baseline: bool
    started: str
    wall_s: float = 0.0
    notes: list[str] = field(default_factory=list)
    report_dir: str | None = None
    max_rows: int = 200  # markdown rows of changes per study (the JSON has them all)
    catalogued: str | None = None  # the service's URL of this report (runs through --url)
    catalogue_error: str | None = None  # why a run through --url could not catalogue it

    @property
    def ok(self) -> bool:
        """Every study passed (or, updating, had its baseline written)."""
        return bool(self.studies) and all(s.ok for s in self.studies)

    def summary(self) -> str:
        """One line: how many studies and points, and which studies are not ok and why."""
        n, pts = len(self.studies), sum(s.points for s in self.studies)
        head = f"{n} stud{'y' if n == 1 else 'ies'}, {pts} points"
        bad = [s for s in self.studies if not s.ok]
        if not bad:
            if self.update_baseline:
                changed = sum(1 for s in self.studies if s.changes or s.status == "created")
                return f"{head}: baselines written ({changed} new or changed)"
            return f"{head}: no regressions"
        parts = []
        for s in bad:
            why = [f"{len(s.regressions)} changed points"] if s.regressions else []
            if s.failed_checks:
                why.append(f"{len(s.failed_checks)} failed distribution checks")
            parts.append(f"{s.study} {s.status}" + (f" ({', '.join(why)})" if why else ""))
        return f"{head}: {len(bad)} not ok: " + "; ".join(parts)

    def to_json(self) -> dict[str, Any]:
        """JSON-ready dict: the run, then one entry per study with every change (paths as they
        are: tools read it on the machine that ran it; the service shows them relative)."""
        return {
            "ok": self.ok,
            "summary": self.summary(),
            "started": self.started,
            "wall_s": self.wall_s,
            "mode": self.mode,
            "suite": self.suite,
            "baselines": self.baselines,
            "update_baseline": self.update_baseline,
            "notes": self.notes,
            "studies": [s.to_json() for s in self.studies],
        }

    def to_markdown(self) -> str:
        """A markdown report: a summary table, then every moved point and failed check."""
        if self.update_baseline:
            verdict = "BASELINES UPDATED" if self.ok else "BASELINE UPDATE INCOMPLETE"
        else:
            verdict = "PASSED" if self.ok else "FAILED"
        lines = [
            f"# Nightly regression: {verdict}",
            "",
            f"Started {self.started}, {self.wall_s:.1f} s, mode {self.mode}. Suite `{self.suite}`, "
            f"baselines `{self.baselines}` (paths relative to the suite's parent folder; results "
            "relative to this report's folder).",
            "",
            self.summary() + ".",
            "",
            "| study | points | linear | periodic | irregular | unsettled | failed | status | "
            "changes | distribution checks |",
            "|---|---|---|---|---|---|---|---|---|---|",
        ]
        for s in self.studies:
            c = s.counts.get("new", {})
            n_checks = len(s.distribution)
            checks = f"{n_checks - len(s.failed_checks)}/{n_checks} ok" if n_checks else "-"
            changes = len(s.regressions) if not self.update_baseline else len(s.changes)
            per = " | ".join(str(c.get(k, "")) for k in OUTCOMES)
            lines.append(f"| {s.study} | {s.points} | {per} | {s.status} | {changes} | {checks} |")
        rows = [(s, ch) for s in self.studies for ch in s.changes]
        if rows:
            title = "Changes written to the baselines" if self.update_baseline else "Moved points"
            lines += [
                "",
                f"## {title}",
                "",
                "| study | coordinates | variable | kind | old | new | abs diff | tolerance |",
                "|---|---|---|---|---|---|---|---|",
            ]
            shown: dict[str, int] = {}
            for s, ch in rows:
                shown[s.study] = shown.get(s.study, 0) + 1
                if shown[s.study] > self.max_rows:
                    continue
                kind = ch.kind if ch.regression else f"{ch.kind} (sensitive, not a regression)"
                lines.append(
                    f"| {s.study} | {_coords_text(ch.coords)} | {ch.variable} | {kind} | "
                    f"{_fmt(ch.old)} | {_fmt(ch.new)} | "
                    f"{'-' if ch.kind == 'outcome' else _fmt(ch.delta, 3)} | {ch.tolerance} |"
                )
            for study, n in shown.items():
                if n > self.max_rows:
                    lines.append(f"\n{study}: {n - self.max_rows} more rows in report.json.")
        dist = [(s, d) for s in self.studies for d in s.distribution]
        if dist:
            lines += [
                "",
                "## Irregular points (distribution checks)",
                "",
                "| study | variable | check | value | limit | points old/new/paired | result |",
                "|---|---|---|---|---|---|---|",
            ]
            for s, d in dist:
                result = f"skipped: {d.skipped}" if d.skipped else ("ok" if d.passed else "FAIL")
                lines.append(
                    f"| {s.study} | {d.variable} | {d.check} | {_fmt(d.value, 4)} | {d.limit:g} "
                    f"| {d.n_old}/{d.n_new}/{d.n_paired} | {result} |"
                )
        msgs = [
            (s.study, m)
            for s in self.studies
            for m in ([s.error] if s.error else []) + s.problems + s.notes
        ]
        msgs += [("suite", n) for n in self.notes]
        if msgs:
            lines += ["", "## Notes and errors", ""]
            lines += [f"- {who}: {m}" for who, m in msgs]
        return self._relative_paths()("\n".join(lines) + "\n")

    def _relative_paths(self) -> Callable[[str], str]:
        """A function that rewrites the run's absolute paths in a text relative to the suite's
        parent folder (suite, baselines) or this report's folder (results): a report read on
        another machine, or served by the service, shows no server paths."""
        suite, base = Path(self.suite), Path(self.baselines)
        root = suite.parent
        shown: dict[str, str] = {}
        # Absolute paths only (relative ones are not the server's), never "/" itself.
        if root.is_absolute() and len(root.parts) > 1:
            shown[str(root)] = "."
            shown[str(suite)] = os.path.relpath(suite, root)
            if base.is_absolute():
                shown[str(base)] = os.path.relpath(base, root)
        if self.report_dir and Path(self.report_dir).is_absolute():
            shown[str(Path(self.report_dir))] = "."
        if not shown:
            return lambda text: text
        keys = sorted(shown, key=len, reverse=True)  # the longest (most specific) path first
        alternatives = "|".join(re.escape(k) for k in keys)
        pattern = re.compile(rf"(?<![\w/.-])({alternatives})(?![\w.-])(/)?")

        def sub(m: re.Match[str]) -> str:
            rel = shown[m.group(1)]
            if m.group(2):  # a path inside: drop a leading "./"
                return "" if rel == "." else rel + "/"
            return rel

        return lambda text: pattern.sub(sub, text)

    def write(self, directory: str | os.PathLike[str]) -> tuple[Path, Path]:
        """Write ``report.json`` and ``report.md`` into ``directory``."""
        d = Path(directory)
        self.report_dir = str(d)
        text_json = json_text(self.to_json(), indent=1)
        text_md = self.to_markdown()
        pj, pm = d / "report.json", d / "report.md"
        atomic_write(pj, lambda p: p.write_text(text_json, encoding="utf-8"))
        atomic_write(pm, lambda p: p.write_text(text_md, encoding="utf-8"))
        return pj, pm


def map_text(fn: Callable[[str], str], data: Any) -> Any:
    """``data`` with ``fn`` applied to every string in it (keys too)."""
    if isinstance(data, str):
        return fn(data)
    if isinstance(data, dict):
        return {map_text(fn, k): map_text(fn, v) for k, v in data.items()}
    if isinstance(data, list | tuple):
        return [map_text(fn, v) for v in data]
    return data
