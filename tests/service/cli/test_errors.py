"""Errors of the command line: one line on stderr, no traceback, exit 2 for bad usage and 1 for
failures; flags named as typed; addresses checked before any work; every option's default in
``--help``.

In process (``main(argv)``) unless marked ``slow``; the ``slow`` ones run the same cases as a
user does, in a new Python process. Nothing here reaches beyond 127.0.0.1: "unreachable" is a
port on the loopback that nobody listens on.
"""

from __future__ import annotations

import argparse
import json
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
import xarray as xr
import yaml

from service.api.server import free_port
from service.cli import build_parser, main
from service.cli.common import HelpFormatter
from service.cli.simulate import FIELD_FLAGS, in_flag_terms
from tests.service.helpers import run_cli as run
from tests.service.helpers import tiny_study

ROOT = Path(__file__).resolve().parents[3]


def one_error_line(stderr: str) -> str:
    """The one error line a failed command printed last, with no traceback (progress lines
    before it, such as the numba compilation notice, are allowed)."""
    lines = stderr.strip().splitlines()
    assert lines and "Traceback" not in stderr, stderr
    assert sum("error:" in line for line in lines) == 1, stderr
    assert "error:" in lines[-1], stderr
    return lines[-1]


@pytest.fixture
def closed_port() -> int:
    """A loopback port nobody listens on (connections are refused at once)."""
    return free_port()


@pytest.fixture
def listening() -> Iterator[int]:
    """A loopback port that is in use (bound and listening) for the test."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        yield int(s.getsockname()[1])


@pytest.fixture
def study_file(tmp_path: Path) -> Path:
    f = tmp_path / "s.yaml"
    f.write_text(yaml.safe_dump(tiny_study(num=4)))
    return f


# --------------------------------------------------------------------------- the service


@pytest.mark.parametrize("command", ["status", "submit"])
def test_no_service_running_is_a_failure_naming_the_address(
    command: str, closed_port: int, study_file: Path
) -> None:
    url = f"http://127.0.0.1:{closed_port}"
    args = [command, *([str(study_file)] if command == "submit" else []), "--url", url]
    t0 = time.monotonic()
    out = run(*args)
    assert time.monotonic() - t0 < 15
    assert out.returncode == 1
    line = one_error_line(out.stderr)
    assert line.startswith("impactcell: error: cannot reach the impactcell service at ")
    assert url in line and "--url" in line


def test_a_url_that_is_not_one_is_bad_usage(
    monkeypatch: pytest.MonkeyPatch, study_file: Path
) -> None:
    out = run("status", "--url", "notaurl")
    assert out.returncode == 2
    line = one_error_line(out.stderr)
    assert "--url 'notaurl' is not an http(s) URL" in line
    monkeypatch.setenv("IMPACTCELL_URL", "ftp://example.invalid")
    out = run("submit", str(study_file))
    assert out.returncode == 2
    assert "IMPACTCELL_URL 'ftp://example.invalid'" in one_error_line(out.stderr)
    out = run("status", "--url", "http://127.0.0.1:99999")
    assert out.returncode == 2 and "not a valid URL" in one_error_line(out.stderr)


def test_submit_of_an_unreadable_study_file_is_bad_usage(tmp_path: Path) -> None:
    f = tmp_path / "binary.yaml"
    f.write_bytes(b"\xff\xfe\x00bad")
    out = run("submit", str(f), "--url", "http://127.0.0.1:1")
    assert out.returncode == 2
    assert f"cannot read study file {f}" in one_error_line(out.stderr)


# --------------------------------------------------------------------------- the scheduler


def test_unreachable_scheduler_fails_within_seconds(
    closed_port: int, study_file: Path, tmp_path: Path
) -> None:
    address = f"tcp://127.0.0.1:{closed_port}"
    t0 = time.monotonic()
    out = run("run", str(study_file), "--scheduler", address, "--out", str(tmp_path / "d"),
              "--no-progress")  # fmt: skip
    elapsed = time.monotonic() - t0
    assert out.returncode == 1
    line = one_error_line(out.stderr)
    assert f"cannot reach the dask scheduler at {address}" in line and "--scheduler" in line
    assert elapsed < 15, f"took {elapsed:.1f} s (dask alone waits 30 s)"
    assert not (tmp_path / "d" / "studies").exists()  # nothing ran


def test_unreachable_scheduler_from_the_environment_is_named_so(
    closed_port: int, study_file: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("IMPACTCELL_SCHEDULER", f"tcp://127.0.0.1:{closed_port}")
    out = run("run", str(study_file), "--out", str(tmp_path / "d"), "--no-progress")
    assert out.returncode == 1 and "(IMPACTCELL_SCHEDULER)" in one_error_line(out.stderr)


@pytest.mark.parametrize("address", ["tcp://127.0.0.1", "tcp://:8786", "tcp://host:port"])
def test_a_malformed_scheduler_address_is_bad_usage(
    address: str, study_file: Path, tmp_path: Path
) -> None:
    out = run("run", str(study_file), "--scheduler", address, "--out", str(tmp_path))
    assert out.returncode == 2
    assert f"--scheduler {address!r} is not a scheduler address" in one_error_line(out.stderr)


# --------------------------------------------------------------------------- point, spectrum


def test_errors_name_the_flag_the_user_typed() -> None:
    out = run("point", "--gap", "-0.1")
    assert out.returncode == 2
    line = one_error_line(out.stderr)
    assert line.startswith("impactcell: error: --gap must be ") and "-0.1" in line
    assert "g1" not in line
    out = run("point", "--g2", "nan")
    assert out.returncode == 2 and "--g2 must be finite, got nan" in one_error_line(out.stderr)
    out = run("point", "--xi-b", "-1")
    assert out.returncode == 2
    assert one_error_line(out.stderr).startswith("impactcell: error: --xi-b ")


def test_an_absurd_frequency_is_a_one_line_error_naming_the_flag() -> None:
    # The model refuses γ_r = 1e308 (a bound in worker.model.params) or the point fails; either
    # way one line, no traceback, and the internal field name never shows.
    out = run("point", "--gamma-r", "1e308")
    assert out.returncode in (1, 2)
    line = one_error_line(out.stderr)
    assert "gamma_r" not in line
    if out.returncode == 2:
        assert line.startswith("impactcell: error: --gamma-r ")


def test_the_model_errors_are_translated_whatever_their_text(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    import worker.model

    def refuse(**kw: object) -> None:
        raise ValueError("gamma_r must be <= 1000, got 1e+308 (g1 and xi_b are fine)")

    monkeypatch.setattr(worker.model, "CellParams", refuse)
    out = run("point", "--gamma-r", "1e308")
    assert out.returncode == 2
    assert one_error_line(out.stderr) == (
        "impactcell: error: --gamma-r must be <= 1000, got 1e+308 (--gap and --xi-b are fine)"
    )
    monkeypatch.undo()
    # A spectrum names the end of its range that is out of bounds.
    out = run("spectrum", "--gamma-r-start", "0.5", "--gamma-r-stop", "-1")
    assert out.returncode == 2
    assert one_error_line(out.stderr).startswith("impactcell: error: --gamma-r-stop must be")


def test_in_flag_terms_only_rewrites_field_names() -> None:
    names = {**FIELD_FLAGS, "g1": "--gap"}
    assert in_flag_terms("g1 must be >= 0, got -0.1", names) == "--gap must be >= 0, got -0.1"
    assert in_flag_terms("theta must be > 0", names) == "--theta must be > 0"
    # Plain words in the prose stay, and so do field-like names that are not fields.
    text = "the method needs theta_eff; window must be < max_periods (100)"
    assert in_flag_terms(text, names) == (
        "the method needs theta_eff; window must be < --max-periods (100)"
    )
    assert set(FIELD_FLAGS.values()) <= _options("point")


def test_a_failed_point_exits_1_with_its_reason() -> None:
    # Undamped, on resonance: the solver proves at once that there is no steady state.
    out = run("point", "--xi", "0", "--gamma-r", "1.0", "--json")
    assert out.returncode == 1
    record = json.loads(out.stdout)  # the record is still printed
    assert record["failed"] is True and record["outcome"] == "failed"
    line = one_error_line(out.stderr)
    assert line == f"impactcell: error: the point failed: {record['reason']}"
    plain = run("point", "--xi", "0", "--gamma-r", "1.0")
    assert plain.returncode == 1 and plain.stdout == ""
    assert "undamped resonance" in one_error_line(plain.stderr)


def test_bad_flag_values_are_one_line_usage_errors() -> None:
    out = run("point", "--gap", "wide")
    assert out.returncode == 2
    line = one_error_line(out.stderr)
    assert "argument --gap: invalid float value: 'wide'" in line
    assert "impactcell point --help" in line
    out = run("spectrum", "--num", "0")
    assert out.returncode == 2 and "--num: must be >= 1, got 0" in one_error_line(out.stderr)


# --------------------------------------------------------------------------- files


def test_show_on_a_file_that_is_not_a_study_is_bad_usage(tmp_path: Path) -> None:
    nc = tmp_path / "other.nc"
    xr.Dataset({"a": ("x", [1.0, 2.0])}).to_netcdf(nc)
    out = run("show", str(nc))
    assert out.returncode == 2
    assert f"{nc} is not an impactcell results file" in one_error_line(out.stderr)
    text = tmp_path / "notes.txt"
    text.write_text("hello")
    out = run("show", str(text))
    assert out.returncode == 2 and "is not a readable NetCDF file" in one_error_line(out.stderr)


def test_demo_out_where_no_folder_can_be_made_is_bad_usage(tmp_path: Path) -> None:
    blocker = tmp_path / "a-file"
    blocker.write_text("")
    out = run("demo", "--out", str(blocker / "demo"), "--no-progress")
    assert out.returncode == 2
    line = one_error_line(out.stderr)
    assert f"--out {blocker / 'demo'}: cannot create the folder" in line


# --------------------------------------------------------------------------- serve, settings


def test_serve_on_a_port_in_use_fails_before_starting_anything(
    listening: int, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    import uvicorn

    def started(*a: object, **kw: object) -> None:
        raise AssertionError("uvicorn was started")

    monkeypatch.setattr(uvicorn, "run", started)
    data = tmp_path / "data"
    out = run("serve", "--port", str(listening), "--data-dir", str(data))
    assert out.returncode == 2
    line = one_error_line(out.stderr)
    assert f"--port {listening}: 127.0.0.1:{listening} is already in use" in line
    assert not data.exists()  # no catalogue, no data folder: nothing was started


@pytest.mark.parametrize(
    ("url", "code", "says"),
    [
        ("not a url", 2, "is not one SQLAlchemy reads"),
        ("nosuchdb://x/y", 2, "is not one SQLAlchemy reads"),
        ("postgresql+psycopg://u:pw@127.0.0.1:1/db", 1, "catalogue postgresql+psycopg://u:***@"),
    ],
)
def test_serve_with_a_bad_database_url_says_so_in_one_line(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, url: str, code: int, says: str
) -> None:
    out = run("serve", "--port", "0", "--data-dir", str(tmp_path / "d"), "--database-url", url)
    assert out.returncode == code, out.stderr
    line = one_error_line(out.stderr)
    assert says in line and "Traceback" not in out.stderr and "pw@" not in out.stderr


def test_settings_errors_name_the_variable_its_value_and_what_is_allowed(
    monkeypatch: pytest.MonkeyPatch, study_file: Path
) -> None:
    monkeypatch.setenv("IMPACTCELL_MAX_POINTS", "lots")
    out = run("run", str(study_file), "--serial")
    assert out.returncode == 2
    line = one_error_line(out.stderr)
    assert line == (
        "impactcell: error: IMPACTCELL_MAX_POINTS 'lots': must be a valid integer, unable to "
        "parse string as an integer"
    )
    monkeypatch.delenv("IMPACTCELL_MAX_POINTS")
    out = run("serve", "--port", "70000")
    assert out.returncode == 2
    assert "--port 70000: must be less than or equal to 65535" in one_error_line(out.stderr)
    monkeypatch.setenv("IMPACTCELL_NIGHTLY_CRON", "every night")
    out = run("serve", "--port", "0")
    assert out.returncode == 2
    line = one_error_line(out.stderr)
    assert "IMPACTCELL_NIGHTLY_CRON: nightly_cron must be a 5-field cron expression" in line
    assert "'every night'" in line and "pydantic" not in line and "errors.pydantic" not in line


# --------------------------------------------------------------------------- help


Commands = Iterator[tuple[str, argparse.ArgumentParser]]


def _subparsers(parser: argparse.ArgumentParser, prefix: str = "") -> Commands:
    yield prefix or "impactcell", parser
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield from _subparsers(sub, f"{prefix} {name}".strip())


def _options(command: str) -> set[str]:
    parsers = dict(_subparsers(build_parser()))
    return set(parsers[command]._option_string_actions)


def test_help_shows_the_default_of_every_option(capsys: pytest.CaptureFixture[str]) -> None:
    missing = []
    commands = list(_subparsers(build_parser()))
    assert len(commands) > 15  # every command and db subcommand
    for name, parser in commands:
        fmt = HelpFormatter(parser.prog)
        for action in parser._actions:
            if not action.option_strings or action.default is argparse.SUPPRESS:
                continue
            if action.required:  # nothing to default to
                continue
            if "default" not in fmt._get_help_string(action).lower():
                missing.append(f"{name} {action.option_strings[-1]}")
    assert not missing, f"options whose --help does not say the default: {missing}"
    with pytest.raises(SystemExit):
        main(["point", "--help"])
    text = capsys.readouterr().out
    assert "(default: 0.3)" in text and "(default: paper)" in text and "(default: off)" in text


def test_every_command_has_a_description_and_version_names_both_versions(
    capsys: pytest.CaptureFixture[str],
) -> None:
    from service.studies.provenance import package_version
    from worker.simulate import SOLVER_VERSION

    bare = [name for name, parser in _subparsers(build_parser()) if not parser.description]
    assert not bare, f"commands whose --help has no description: {bare}"
    with pytest.raises(SystemExit) as done:
        main(["--version"])
    assert done.value.code == 0
    out = capsys.readouterr().out
    assert out == f"impactcell {package_version()} (solver version {SOLVER_VERSION})\n"


# --------------------------------------------------------------------------- the point store


def test_a_bad_number_names_the_flag_and_no_internal_name() -> None:
    out = run("points", "--theta", "abc")
    assert out.returncode == 2
    line = one_error_line(out.stderr)
    assert "argument --theta: must be a number, got 'abc'" in line and "_float" not in line
    out = run("points", "--gap-min", "inf")
    assert "argument --gap-min: must be a finite number, got 'inf'" in one_error_line(out.stderr)


@pytest.mark.parametrize("command", [["gc", "--dry-run"], ["gc"], ["points"]])
def test_a_data_dir_without_a_catalogue_is_bad_usage_and_creates_nothing(
    command: list[str], tmp_path: Path
) -> None:
    typo = tmp_path / "typo"
    out = run(*command, "--data-dir", str(typo))
    assert out.returncode == 2
    assert f"--data-dir {typo}: no such folder" in one_error_line(out.stderr)
    assert not typo.exists()
    empty = tmp_path / "empty"
    empty.mkdir()
    out = run(*command, "--data-dir", str(empty))
    assert out.returncode == 2
    assert f"no catalogue database at {empty / 'catalogue.sqlite'}" in one_error_line(out.stderr)
    assert list(empty.iterdir()) == []


# --------------------------------------------------------------------------- answers of a server


@pytest.fixture
def not_impactcell(tmp_path: Path) -> Iterator[str]:
    """A real HTTP server on the loopback that is not impactcell: it serves an HTML page."""
    import functools
    import http.server
    import threading

    (tmp_path / "index.html").write_text("<html>\n<body>\n<h1>Welcome</h1>\n</body>\n</html>\n")

    class Quiet(http.server.SimpleHTTPRequestHandler):
        def log_message(self, *args: object) -> None:
            pass

    handler = functools.partial(Quiet, directory=str(tmp_path))
    srv = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
    thread = threading.Thread(target=srv.serve_forever, daemon=True)
    thread.start()
    yield f"http://127.0.0.1:{srv.server_address[1]}"
    srv.shutdown()
    thread.join()


@pytest.mark.parametrize(
    ("args", "answer"),
    [
        (["status"], "GET /studies answered HTTP 404 File not found with text/html"),
        (["status", "abc12345"], "GET /studies/abc12345 answered HTTP 404"),
        (["submit", "STUDY"], "POST /studies answered HTTP 501"),
    ],
)
@pytest.mark.slow  # a real HTTP server on the loopback
def test_a_server_that_is_not_impactcell_is_one_line_without_its_page(
    args: list[str], answer: str, not_impactcell: str, study_file: Path
) -> None:
    argv = [str(study_file) if a == "STUDY" else a for a in args]
    out = run(*argv, "--url", not_impactcell)
    assert out.returncode in (1, 2) and out.stdout == ""
    line = one_error_line(out.stderr)
    assert out.stderr.strip() == line  # one line: no page
    assert f"{not_impactcell} is not an impactcell service: {answer}" in line
    assert "<" not in line and "Welcome" not in out.stderr


def test_the_services_problems_are_printed_once(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    from fastapi.testclient import TestClient

    from service.api.app import create_app
    from service.api.settings import Settings
    from service.cli import service as service_cli
    from service.client import Client
    from tests.service.cli.test_study import ADAPTIVE
    from tests.service.helpers import AppTransport

    bad = tiny_study()
    bad["grid"]["gamma_r"]["num"] = -3
    bad["colour"] = "blue"
    (tmp_path / "bad.yaml").write_text(yaml.safe_dump(bad))
    (tmp_path / "adaptive.yaml").write_text(yaml.safe_dump(ADAPTIVE))
    with TestClient(create_app(Settings(data_dir=tmp_path / "data"), run_jobs=False)) as tc:
        monkeypatch.setattr(
            service_cli,
            "_client",
            lambda args: Client("http://testserver", transport=AppTransport(tc)),
        )
        out = run("submit", str(tmp_path / "bad.yaml"))
        assert out.returncode == 2
        assert out.stderr.startswith("impactcell: error: body: 2 problems\n")
        assert out.stderr.count("grid.gamma_r.num") == 1
        assert out.stderr.count("colour: unknown key") == 1
        # an adaptive study's total is the most it may take
        out = run("submit", str(tmp_path / "adaptive.yaml"))
        assert out.returncode == 0 and out.stdout.rstrip().endswith("queued  up to 30 points")


# --------------------------------------------------------------------------- real processes


def _subprocess(*args: str, env: dict[str, str] | None = None) -> subprocess.CompletedProcess:
    import os

    return subprocess.run(
        [sys.executable, "-m", "service.cli", *args], capture_output=True, text=True,
        timeout=120, cwd=ROOT, env={**os.environ, **(env or {})},
    )  # fmt: skip


@pytest.mark.slow  # new Python processes
def test_the_same_errors_in_a_real_process(
    closed_port: int, listening: int, tmp_path: Path
) -> None:
    cases = [
        (["status", "--url", f"http://127.0.0.1:{closed_port}"], {}, 1, "cannot reach"),
        (
            [
                "run",
                "quick",
                "--scheduler",
                f"tcp://127.0.0.1:{closed_port}",
                "--out",
                str(tmp_path),
            ],
            {},
            1,
            "cannot reach the dask scheduler",
        ),  # fmt: skip
        (["point", "--xi", "0", "--gamma-r", "1"], {}, 1, "the point failed"),
        (["status", "--url", "notaurl"], {}, 2, "not an http(s) URL"),
        (["point", "--gap", "-1"], {}, 2, "--gap must be"),
        (
            ["serve", "--port", str(listening), "--data-dir", str(tmp_path / "d")],
            {},
            2,
            "already in use",
        ),  # fmt: skip
        (["serve", "--port", "0"], {"IMPACTCELL_WORKERS": "none"}, 2, "IMPACTCELL_WORKERS 'none'"),
    ]
    for argv, env, code, text in cases:
        t0 = time.monotonic()
        p = _subprocess(*argv, env=env)
        assert p.returncode == code, (argv, p.stderr)
        assert text in one_error_line(p.stderr), argv
        assert time.monotonic() - t0 < 60, argv
    assert not (tmp_path / "d").exists()


_ENTRY = """
import atexit, sys, threading, time
atexit.register(lambda: print("atexit handler ran", flush=True))
def late():
    while threading.main_thread().is_alive():  # until the command is done, and then some
        time.sleep(0.01)
    time.sleep(0.2)
    print("thread finished", flush=True)
threading.Thread(target=late).start()
sys.argv = ["impactcell", *sys.argv[1:]]
from service.cli import entry
entry()
"""


@pytest.mark.slow  # new Python processes
@pytest.mark.parametrize(("argv", "code"), [(["studies"], 0), (["show", "/nonexistent.nc"], 2)])
def test_the_command_exits_quickly_but_completely(argv: list[str], code: int) -> None:
    """``entry`` skips the interpreter's teardown, not what a normal exit does: other threads
    finish, atexit handlers run, everything printed arrives, the exit status is main's."""
    p = subprocess.run(
        [sys.executable, "-c", _ENTRY, *argv], capture_output=True, text=True, timeout=120,
        cwd=ROOT,
    )  # fmt: skip
    assert p.returncode == code, p.stderr
    lines = p.stdout.splitlines()
    assert lines[-2:] == ["thread finished", "atexit handler ran"]
    if code == 0:  # every shipped study listed, the last one included
        assert len(lines) - 2 == len(list((ROOT / "studies").glob("*.yaml")))
    else:
        assert "no such results file" in p.stderr


@pytest.mark.slow  # a new Python process under the profiler
def test_a_profiled_command_still_writes_its_profile(tmp_path: Path) -> None:
    out = tmp_path / "studies.prof"
    p = subprocess.run(
        [sys.executable, "-m", "cProfile", "-o", str(out), "-m", "service.cli", "studies"],
        capture_output=True, text=True, timeout=120, cwd=ROOT,
    )  # fmt: skip
    assert p.returncode == 0, p.stderr
    assert out.stat().st_size > 0
    assert "quick" in p.stdout
