"""The deployment files (Dockerfile, docker-compose.yml) agree with the spec, the CLI and Settings.

No Docker engine is needed: the compose file is validated against the Compose Specification's
JSON schema (``../shared/compose-spec.json`` beside the repository, or the file named by
``IMPACTCELL_COMPOSE_SCHEMA``), and its commands, ports and environment are checked against
``impactcell serve``'s parser and ``service.api.settings.Settings``.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shlex
import subprocess
import sys
import threading
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from typing import Any

import pytest
import yaml

ROOT = Path(__file__).resolve().parents[1]
COMPOSE = ROOT / "docker-compose.yml"
DOCKERFILE = ROOT / "Dockerfile"
ENV_PREFIX = "IMPACTCELL_"


# --------------------------------------------------------------------------------------------
# helpers


def _compose() -> dict[str, Any]:
    return yaml.safe_load(COMPOSE.read_text())


def _service(name: str) -> dict[str, Any]:
    services = _compose()["services"]
    assert name in services, f"docker-compose.yml has no service {name!r}"
    return services[name]


def _argv(command: str | list[Any]) -> list[str]:
    """A compose ``command`` (string or list) as an argv list of strings."""
    if isinstance(command, str):
        return shlex.split(command)
    return [str(a) for a in command]


def _option(argv: list[str], name: str) -> str:
    """The value of ``--name VALUE`` or ``--name=VALUE`` in argv."""
    for i, arg in enumerate(argv):
        if arg == name and i + 1 < len(argv):
            return argv[i + 1]
        if arg.startswith(name + "="):
            return arg.split("=", 1)[1]
    raise AssertionError(f"{name} not in {argv}")


def _long_options(argv: list[str]) -> list[str]:
    return [a.split("=", 1)[0] for a in argv if a.startswith("--")]


def _subparser(parser: argparse.ArgumentParser, name: str) -> argparse.ArgumentParser:
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            if name in action.choices:
                return action.choices[name]
            raise AssertionError(
                f"`impactcell {name}` is not registered; subcommands: {sorted(action.choices)}"
            )
    raise AssertionError("the impactcell parser has no subcommands")


def _cli_parser() -> argparse.ArgumentParser:
    from service.cli import build_parser

    return build_parser()


def _check_cli_args(argv: list[str], subcommand: str) -> tuple[argparse.ArgumentParser, Any]:
    """Every ``--option`` of ``impactcell SUBCOMMAND ...`` is one its parser accepts."""
    assert argv[:2] == ["impactcell", subcommand], f"expected `impactcell {subcommand} ...`: {argv}"
    parser = _cli_parser()
    sub = _subparser(parser, subcommand)
    known = set(sub._option_string_actions)
    unknown = [o for o in _long_options(argv[2:]) if o not in known]
    assert not unknown, (
        f"`impactcell {subcommand}` does not accept {unknown}; it has {sorted(known)}"
    )
    try:
        args = parser.parse_args(argv[1:])
    except SystemExit as exc:  # argparse reports bad values on stderr and exits
        raise AssertionError(f"`impactcell {subcommand}` rejects {argv[2:]}") from exc
    return sub, args


def _settings_fields() -> set[str]:
    from service.api.settings import Settings

    return set(Settings.model_fields)


def _env_names(service: dict[str, Any]) -> dict[str, str | None]:
    env = service.get("environment") or {}
    if isinstance(env, list):  # ["NAME=value", "NAME"]
        return {
            item.split("=", 1)[0]: (item.split("=", 1)[1] if "=" in item else None) for item in env
        }
    return {k: None if v is None else str(v) for k, v in env.items()}


def _ports(service: dict[str, Any]) -> list[tuple[int | None, int]]:
    """(published, target) pairs of a service's ``ports`` (short and long syntax)."""
    out = []
    for p in service.get("ports") or []:
        if isinstance(p, dict):
            pub = p.get("published")
            out.append((None if pub is None else int(pub), int(p["target"])))
            continue
        spec = str(p).split("/", 1)[0]  # drop /tcp
        parts = spec.rsplit(":", 2)
        if len(parts) == 1:
            out.append((None, int(parts[0])))
        else:
            out.append((int(parts[-2]), int(parts[-1])))
    return out


def _healthcheck_code(service: dict[str, Any]) -> str:
    test = service["healthcheck"]["test"]
    argv = test[1:] if isinstance(test, list) else ["sh", "-c", test]
    assert argv[0] in ("python", "python3") and argv[1] == "-c", f"python -c expected: {test}"
    return argv[2]


def _dockerfile() -> list[tuple[str, str]]:
    """(INSTRUCTION, arguments) of the Dockerfile, continuation lines joined, comments dropped."""
    out: list[tuple[str, str]] = []
    buf = ""
    for raw in DOCKERFILE.read_text().splitlines():
        line = raw.strip()
        if not buf and (not line or line.startswith("#")):
            continue
        if buf and line.startswith("#"):
            continue
        if line.endswith("\\"):
            buf += line[:-1] + " "
            continue
        buf += line
        word, _, rest = buf.strip().partition(" ")
        out.append((word.upper(), rest.strip()))
        buf = ""
    return out


def _instructions(name: str) -> list[str]:
    return [args for word, args in _dockerfile() if word == name]


def _exec_form(args: str) -> list[str]:
    try:
        value = json.loads(args)
    except json.JSONDecodeError:
        return shlex.split(args)
    assert isinstance(value, list), args
    return [str(v) for v in value]


def _docker_env() -> dict[str, str]:
    env: dict[str, str] = {}
    for args in _instructions("ENV"):
        parts = shlex.split(args)
        if len(parts) >= 2 and "=" not in parts[0]:  # legacy "ENV NAME value"
            env[parts[0]] = " ".join(parts[1:])
        else:
            env.update(p.split("=", 1) for p in parts)
    return env


# --------------------------------------------------------------------------------------------
# the Compose Specification


def _schema_path() -> Path:
    override = os.environ.get("IMPACTCELL_COMPOSE_SCHEMA")
    return Path(override) if override else ROOT.parent / "shared" / "compose-spec.json"


_DRAFTS = {
    "draft-03": "Draft3Validator",
    "draft-04": "Draft4Validator",
    "draft-06": "Draft6Validator",
    "draft-07": "Draft7Validator",
    "2019-09": "Draft201909Validator",
    "2020-12": "Draft202012Validator",
}


def _validator_class(schema: dict[str, Any]):
    """The jsonschema validator for the draft that the schema's ``$schema`` declares.

    ``validator_for`` knows only the canonical URIs (``http://json-schema.org/draft-07/schema#``);
    the compose schema writes ``https://…/draft-07/schema``, for which it would silently fall back
    to the newest draft. So the draft is read off the URI.
    """
    import jsonschema
    from jsonschema.validators import validator_for

    declared = schema.get("$schema")
    if not declared:
        return jsonschema.Draft7Validator  # the compose spec's draft
    cls = validator_for(schema, default=None)
    if cls is not None:
        return cls
    for key, name in _DRAFTS.items():
        if key in declared:
            return getattr(jsonschema, name)
    raise AssertionError(f"unknown $schema {declared!r} in the compose schema")


def test_compose_file_matches_compose_specification() -> None:
    path = _schema_path()
    if not path.is_file():
        pytest.skip(
            f"Compose Specification schema not found at {path} "
            "(set IMPACTCELL_COMPOSE_SCHEMA to compose-spec.json to run this check)"
        )
    pytest.importorskip("jsonschema")
    schema = json.loads(path.read_text())
    cls = _validator_class(schema)
    cls.check_schema(schema)
    validator = cls(schema, format_checker=cls.FORMAT_CHECKER)
    errors = sorted(validator.iter_errors(_compose()), key=lambda e: list(e.absolute_path))
    report = "\n".join(
        f"  {'.'.join(map(str, e.absolute_path)) or '<root>'}: {e.message}" for e in errors
    )
    assert not errors, f"docker-compose.yml violates the Compose Specification:\n{report}"


def test_schema_draft_is_read_off_the_declared_uri() -> None:
    jsonschema = pytest.importorskip("jsonschema")
    for uri, cls in [
        ("https://json-schema.org/draft-07/schema", jsonschema.Draft7Validator),
        ("http://json-schema.org/draft-07/schema#", jsonschema.Draft7Validator),
        ("http://json-schema.org/draft-04/schema#", jsonschema.Draft4Validator),
        ("https://json-schema.org/draft/2020-12/schema", jsonschema.Draft202012Validator),
    ]:
        assert _validator_class({"$schema": uri}) is cls, uri
    # A file that breaks the spec is caught (so the check above can fail).
    path = _schema_path()
    if path.is_file():
        schema = json.loads(path.read_text())
        cls = _validator_class(schema)
        bad = {"services": {"api": {"image": "x", "ports": [{"no_target": 1}], "bogus": 1}}}
        assert list(cls(schema).iter_errors(bad))


# --------------------------------------------------------------------------------------------
# compose file against the CLI and Settings


def test_api_command_is_accepted_by_impactcell_serve() -> None:
    argv = _argv(_service("api")["command"])
    _check_cli_args(argv, "serve")
    # serve's options are Settings fields (the command line overrides the environment).
    fields = _settings_fields()
    sub = _subparser(_cli_parser(), "serve")
    dests = {sub._option_string_actions[o].dest for o in _long_options(argv[2:])}
    assert dests <= fields, f"serve options that are not Settings fields: {dests - fields}"


def test_cli_option_check_rejects_unknown_options() -> None:
    # The parsing logic above, on a subcommand that exists now.
    with pytest.raises(AssertionError, match="does not accept"):
        _check_cli_args(["impactcell", "point", "--theta", "0.3", "--no-such-option"], "point")
    with pytest.raises(AssertionError, match="rejects"):
        _check_cli_args(["impactcell", "point", "--theta", "not-a-number"], "point")
    _, args = _check_cli_args(["impactcell", "point", "--theta", "0.3", "--gap=0.2"], "point")
    assert (args.theta, args.gap) == (0.3, 0.2)


def test_compose_environment_names_are_settings_fields() -> None:
    fields = _settings_fields()
    text = COMPOSE.read_text()
    names = set()
    for service in _compose()["services"].values():
        names |= {n for n in _env_names(service) if n.startswith(ENV_PREFIX)}
    # ...and every ${IMPACTCELL_*} the file interpolates, outside comments.
    code = "\n".join(line.split("#", 1)[0] for line in text.splitlines())
    names |= set(re.findall(r"\$\{?(IMPACTCELL_[A-Z0-9_]+)", code))
    assert names, "no IMPACTCELL_* variables in docker-compose.yml"
    unknown = {n for n in names if n[len(ENV_PREFIX) :].lower() not in fields}
    assert not unknown, f"not fields of service.api.settings.Settings: {sorted(unknown)}"
    api = _env_names(_service("api"))
    for name in ("IMPACTCELL_API_TOKEN", "IMPACTCELL_NIGHTLY_CRON", "IMPACTCELL_DATABASE_URL"):
        assert api.get(name) == f"${{{name}:-}}", f"api should pass {name} through, empty if unset"


def test_empty_compose_variables_mean_unset(monkeypatch: pytest.MonkeyPatch) -> None:
    from service.api.settings import Settings

    for name in _env_names(_service("api")):
        monkeypatch.setenv(name, "")  # what ${VAR:-} gives when VAR is unset on the host
    s = Settings()
    assert s.api_token is None and s.database_url is None and s.nightly_cron is None


def test_api_port_and_healthcheck_agree_with_its_command() -> None:
    api = _service("api")
    argv = _argv(api["command"])
    port = int(_option(argv, "--port"))
    assert _option(argv, "--host") == "0.0.0.0", "in a container the API must listen on 0.0.0.0"
    assert (port, port) in _ports(api), f"api should publish {port}:{port}, has {api['ports']}"
    code = _healthcheck_code(api)
    urls = re.findall(r"https?://(?:127\.0\.0\.1|localhost):(\d+)(/[\w/.-]*)", code)
    assert urls == [(str(port), "/health")], f"healthcheck should GET /health on {port}: {code}"
    data_dir = _option(argv, "--data-dir")
    mounts = [str(v).split(":")[1] for v in api.get("volumes") or [] if ":" in str(v)]
    assert data_dir in mounts, f"the api's --data-dir {data_dir} should be a volume: {mounts}"


class _Health(BaseHTTPRequestHandler):
    status = 200

    def do_GET(self) -> None:  # noqa: N802 (http.server's name)
        self.send_response(self.status if self.path == "/health" else 404)
        self.end_headers()
        self.wfile.write(b'{"status": "ok"}')

    def log_message(self, *args: object) -> None:
        pass


@pytest.mark.slow  # a server and a new Python process each
@pytest.mark.parametrize("service", ["api", "scheduler"])
def test_healthcheck_command_works(service: str) -> None:
    """The healthcheck's python -c exits 0 on 200 from /health, non-zero on an error."""
    svc = _service(service)
    if "healthcheck" not in svc:
        pytest.skip(f"{service} has no healthcheck")
    code = _healthcheck_code(svc)
    (port,) = set(re.findall(r"127\.0\.0\.1:(\d+)", code))
    for status, ok in [(200, True), (500, False)]:
        handler = type("H", (_Health,), {"status": status})
        server = ThreadingHTTPServer(("127.0.0.1", 0), handler)
        thread = threading.Thread(target=server.serve_forever, daemon=True)
        thread.start()
        try:
            probe = code.replace(f"127.0.0.1:{port}", f"127.0.0.1:{server.server_address[1]}")
            rc = subprocess.run([sys.executable, "-c", probe], capture_output=True, timeout=30)
        finally:
            server.shutdown()
            server.server_close()
        assert (rc.returncode == 0) == ok, (status, rc.stderr.decode()[-500:])


def test_worker_and_api_reach_the_scheduler_port() -> None:
    sched = _argv(_service("scheduler")["command"])
    assert sched[:2] == ["dask", "scheduler"], sched
    port = int(_option(sched, "--port"))
    dashboard = int(_option(sched, "--dashboard-address").rsplit(":", 1)[-1])
    published = {target for _, target in _ports(_service("scheduler"))}
    assert {port, dashboard} <= published, f"scheduler should publish {port} and {dashboard}"
    worker = _argv(_service("worker")["command"])
    assert worker[:2] == ["dask", "worker"], worker
    addresses = [a for a in worker[2:] if "://" in a]
    assert addresses == [f"tcp://scheduler:{port}"], worker
    assert _option(worker, "--nthreads") == "1" and _option(worker, "--nworkers") == "1"
    # The nanny pins the CPU target before it starts the worker process (worker/cpu.py).
    assert _option(worker, "--preload-nanny") == "worker"
    api = _argv(_service("api")["command"])
    assert _option(api, "--scheduler") == f"tcp://scheduler:{port}"


def test_workers_scale_and_share_the_image() -> None:
    services = _compose()["services"]
    worker = services["worker"]
    assert "container_name" not in worker, "a container_name stops `--scale worker=N`"
    assert all(pub is None for pub, _ in _ports(worker)), "fixed host ports stop scaling"
    assert "scheduler" in (worker.get("depends_on") or {})
    images = {services[s].get("image") for s in ("scheduler", "worker", "api")}
    assert len(images) == 1 and None not in images, f"one image for all three: {images}"
    assert all(services[s].get("build") for s in ("scheduler", "worker", "api"))


def test_postgres_service_is_optional() -> None:
    services = _compose()["services"]
    pg = services.get("postgres")
    if pg is None:
        pytest.skip("no postgres service")
    assert pg.get("profiles") == ["postgres"], "postgres must sit behind a profile"
    assert any(str(v).startswith("pgdata:") for v in pg.get("volumes") or [])
    assert "pgdata" in (_compose().get("volumes") or {})
    env = _env_names(pg)
    url = (
        f"postgresql+psycopg://{env['POSTGRES_USER']}:{env['POSTGRES_PASSWORD']}"
        f"@postgres:5432/{env['POSTGRES_DB']}"
    )
    assert url in COMPOSE.read_text(), f"compose file should show the URL {url}"


# --------------------------------------------------------------------------------------------
# Dockerfile


def test_dockerfile_cmd_and_expose_agree_on_the_port() -> None:
    (cmd,) = _instructions("CMD")[-1:]
    argv = _exec_form(cmd)
    assert cmd.lstrip().startswith("["), "CMD in exec form, so signals reach the server"
    _check_cli_args(argv, "serve")
    port = _option(argv, "--port")
    assert port == "8000"
    assert _option(argv, "--host") == "0.0.0.0"
    exposed = {p.split("/")[0] for args in _instructions("EXPOSE") for p in args.split()}
    assert port in exposed, f"EXPOSE {port} missing: {exposed}"
    api = _argv(_service("api")["command"])
    assert _option(api, "--port") == port


def test_dockerfile_runs_as_non_root_and_installs_the_package() -> None:
    users = _instructions("USER")
    assert users, "no USER: the container would run as root"
    user = users[-1].split(":")[0]
    assert user not in ("root", "0"), f"last USER is {user}"
    runs = _instructions("RUN")
    installs = [r for r in runs if re.search(r"\bpip install\b", r)]
    assert installs, "the Dockerfile does not pip install the package"
    assert not any(re.search(r"\s(-e|--editable)\b", r) for r in installs), "editable install"
    assert any("[postgres]" in r for r in installs), "install the package with [postgres]"
    env = _docker_env()
    assert env.get("IMPACTCELL_DATA_DIR") == "/data"
    assert "data_dir" in _settings_fields()
    assert env.get("NUMBA_CACHE_DIR"), "numba needs a writable cache dir (site-packages is not)"
    unknown = {n for n in env if n.startswith(ENV_PREFIX)} - {
        ENV_PREFIX + f.upper() for f in _settings_fields()
    }
    assert not unknown, f"Dockerfile sets non-Settings variables {unknown}"
    assert any("/data" in v for v in _instructions("VOLUME"))
    assert _instructions("WORKDIR")[-1:] == ["/app"]


def test_dockerignore_keeps_local_state_out() -> None:
    lines = {ln.strip() for ln in (ROOT / ".dockerignore").read_text().splitlines()}
    for entry in (".git", "data", ".venv*", "**/__pycache__"):
        assert entry in lines, f".dockerignore should exclude {entry}"
