"""What every command shares: the parser and help format, settings from flags, checks of
addresses before any work, and how an error becomes one line and an exit status.

Exit statuses: 0 success; 1 a failure (a point or study that failed, a service or scheduler
that cannot be reached); 2 bad usage (a bad flag or value, a file that cannot be used, an
invalid URL or address, a port in use).
"""

from __future__ import annotations

import argparse
import errno
import math
import socket
import sys
from collections.abc import Mapping
from typing import Any, NoReturn
from urllib.parse import urlsplit

from pydantic import ValidationError

from service.api.settings import Settings

__all__ = [
    "EXIT_FAILURE",
    "EXIT_USAGE",
    "Failure",
    "HelpFormatter",
    "Parser",
    "catalogue_error",
    "check_port_free",
    "check_service_url",
    "error_exit_status",
    "finite_float",
    "positive_int",
    "probe_scheduler",
    "probe_service",
    "settings_from_flags",
]

EXIT_FAILURE = 1
EXIT_USAGE = 2
PROBE_S = 3.0  # a server that does not accept a connection within 3 s is taken to be down


class Failure(Exception):
    """Something the user asked for could not be done (exit status 1, the message on stderr)."""


# --------------------------------------------------------------------------- parser and help


class HelpFormatter(argparse.ArgumentDefaultsHelpFormatter):
    """Every option's help says its default: appended unless the help text already says it."""

    def _get_help_string(self, action: argparse.Action) -> str:
        text = action.help or ""
        if not action.option_strings or action.default is argparse.SUPPRESS:
            return text  # positionals and --help
        if "default" in text.lower():
            return text
        if action.nargs == 0 and action.default is False:  # store_true flags
            return f"{text} (default: off)"
        if action.default is None:
            return text  # a None default must be explained in the help (tests check it)
        return f"{text} (default: %(default)s)"


class Parser(argparse.ArgumentParser):
    """An argument parser with :class:`HelpFormatter` and one-line usage errors (exit 2)."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        kwargs.setdefault("formatter_class", HelpFormatter)
        super().__init__(*args, **kwargs)

    def error(self, message: str) -> NoReturn:
        """Print one line naming the command and the problem, then exit with status 2."""
        self.exit(EXIT_USAGE, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def positive_int(text: str) -> int:
    """An argparse type: an integer >= 1."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be an integer, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be >= 1, got {value}")
    return value


def finite_float(text: str) -> float:
    """An argparse type: a finite number (argparse names the flag before the message)."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be a number, got {text!r}") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"must be a finite number, got {text!r}")
    return value


# --------------------------------------------------------------------------- settings


def _flag(field: str, names: Mapping[str, str]) -> str:
    return names.get(field, "--" + field.replace("_", "-"))


def settings_from_flags(names: Mapping[str, str] | None = None, **flags: Any) -> Settings:
    """``Settings`` from ``IMPACTCELL_*`` variables with the given flags on top.

    Flags that are ``None`` (not given) leave the variable's value or the default. ``names``
    maps a settings field to the flag the user typed where that is not ``--field-name`` (e.g.
    ``{"data_dir": "--out"}``).

    Raises
    ------
    ValueError
        One line naming each bad flag or variable, its value and what is allowed.
    """
    given = {k: v for k, v in flags.items() if v is not None}
    try:
        return Settings(**given)
    except ValidationError as exc:
        problems = []
        for e in exc.errors():
            field = str(e["loc"][0]) if e.get("loc") else "?"
            source = _flag(field, names or {}) if field in given else _env_name(field)
            msg = str(e.get("msg", "invalid"))
            if msg.startswith("Value error, "):  # our validators' text already names the value
                problems.append(f"{source}: {msg.removeprefix('Value error, ')}")
                continue
            msg = msg.replace("Input should be", "must be")
            problems.append(f"{source} {e.get('input')!r}: {msg}")
        raise ValueError("; ".join(problems)) from None


def _env_name(field: str) -> str:
    prefix = str(Settings.model_config.get("env_prefix", ""))
    return f"{prefix}{field}".upper()


# --------------------------------------------------------------------------- addresses


def check_service_url(url: str, source: str = "--url") -> str:
    """``url`` if it is an http(s) URL with a host (else ValueError naming ``source``)."""
    try:
        parts = urlsplit(url)
        port = parts.port  # raises on a port that is not a number or out of range
    except ValueError as exc:
        raise ValueError(f"{source} {url!r} is not a valid URL: {exc}") from None
    if parts.scheme not in ("http", "https") or not parts.hostname:
        raise ValueError(
            f"{source} {url!r} is not an http(s) URL with a host, e.g. http://127.0.0.1:8000"
        )
    del port
    return url


def probe_scheduler(address: str, source: str = "--scheduler") -> None:
    """Fail fast when a dask scheduler address is malformed or nothing listens there.

    dask's own client waits up to its timeout (30 s) for a scheduler that is down; one TCP
    connection with a short timeout tells the same in milliseconds (refused) or seconds.

    Raises
    ------
    ValueError
        The address is not ``tcp://host:port`` (or ``tls://``).
    Failure
        Nothing accepts a connection at the address within a few seconds.
    """
    scheme, sep, rest = address.partition("://")
    if not sep:
        scheme, rest = "tcp", address  # dask reads a bare host:port as tcp
    if scheme not in ("tcp", "tls"):
        return  # inproc://, ucx://: nothing to probe with a socket
    host, colon, port_text = rest.rpartition(":")
    host = host.strip("[]")
    if not colon or not host or not port_text.isdigit() or not 0 < int(port_text) < 65536:
        raise ValueError(f"{source} {address!r} is not a scheduler address like tcp://host:8786")
    _probe(host, int(port_text), f"the dask scheduler at {address}", source)


def probe_service(url: str, source: str = "--url") -> None:
    """Fail fast when nothing accepts a connection at the service URL's host and port.

    Raises
    ------
    ValueError
        ``url`` is not an http(s) URL with a host.
    Failure
        Nothing accepts a connection there within a few seconds.
    """
    check_service_url(url, source)
    parts = urlsplit(url)
    port = parts.port or (443 if parts.scheme == "https" else 80)
    _probe(str(parts.hostname), port, f"the impactcell service at {url}", source)


def _probe(host: str, port: int, what: str, source: str) -> None:
    """One TCP connection with a short timeout, or :class:`Failure` naming ``what``."""
    try:
        with socket.create_connection((host, port), timeout=PROBE_S):
            pass
    except TimeoutError:
        raise Failure(f"cannot reach {what}: no answer within {PROBE_S:g} s ({source})") from None
    except OSError as exc:
        raise Failure(f"cannot reach {what}: {exc.strerror or exc} ({source})") from None


def check_port_free(host: str, port: int) -> None:
    """ValueError when ``host:port`` cannot be bound (in use, or not an address of this host).

    Binding is the last step of the server's start-up; checked first, a taken port fails at
    once instead of after the catalogue and the cluster have started.
    """
    if port == 0:
        return  # the OS picks a free port
    try:
        infos = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE)
    except OSError as exc:
        raise ValueError(f"--host {host!r}: cannot resolve it: {exc.strerror or exc}") from None
    family, kind, proto, _, addr = infos[0]
    with socket.socket(family, kind, proto) as s:
        # As uvicorn binds: a port in TIME_WAIT is free, one with a listener is not.
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            s.bind(addr)
        except OSError as exc:
            if exc.errno == errno.EADDRINUSE:
                raise ValueError(
                    f"--port {port}: {host}:{port} is already in use (another service?); "
                    "choose another port with --port"
                ) from None
            raise ValueError(
                f"--host {host} --port {port}: cannot listen there: {exc.strerror or exc}"
            ) from None


# --------------------------------------------------------------------------- errors


def error_exit_status(exc: BaseException) -> tuple[int, str]:
    """The exit status and one-line message for an error that ended a command."""
    if isinstance(exc, Failure):
        return EXIT_FAILURE, str(exc)
    client = sys.modules.get("service.client")  # only when a command used it
    if client is not None and isinstance(exc, client.ClientError):
        return _service_error(exc)
    httpx = sys.modules.get("httpx")  # only when a command used it: no import for the others
    if httpx is not None:
        if isinstance(exc, httpx.UnsupportedProtocol | httpx.InvalidURL):
            return EXIT_USAGE, f"invalid service URL: {exc}"
        if isinstance(exc, httpx.TransportError):
            return EXIT_FAILURE, f"cannot reach the service at {_base_url(exc)}: {_reason(exc)}"
    if isinstance(exc, ValueError):
        return EXIT_USAGE, str(exc)
    if isinstance(exc, OSError) and exc.strerror:
        where = f": {exc.filename}" if exc.filename else ""
        return EXIT_FAILURE, f"{exc.strerror}{where}"
    text = str(exc).strip().splitlines()
    return EXIT_FAILURE, f"{type(exc).__name__}: {text[0] if text else ''}".rstrip(": ")


def _service_error(exc: Any) -> tuple[int, str]:
    """An error answer of the service: exit 1 for its own failures (5xx), else 2; its message
    with the problems it lists, each once (the service's message usually lists them already)."""
    # One problem per line, unindented: the caller indents the lines after the first.
    message = "\n".join(line.strip() for line in str(exc.message).strip().splitlines())
    extra = [
        f"{p.get('path')}: {p.get('message')}"
        for p in exc.problems or []
        if str(p.get("message")) not in message
    ]
    code = EXIT_FAILURE if exc.status >= 500 else EXIT_USAGE
    return code, "\n".join([message, *extra])


def _base_url(exc: Any) -> str:
    try:
        u = exc.request.url
    except (AttributeError, RuntimeError):  # httpx raises RuntimeError when no request is set
        return "the given URL"
    return f"{u.scheme}://{u.netloc.decode('ascii', 'replace')}"


def _reason(exc: BaseException) -> str:
    # httpx wraps the socket error: "[Errno 111] Connection refused" -> "Connection refused"
    text = str(exc).strip() or type(exc).__name__
    if text.startswith("[Errno"):
        text = text.split("]", 1)[-1].strip()
    return text.splitlines()[0]


def catalogue_error(exc: Exception, shown: str) -> str:
    """One line for an error opening the catalogue at ``shown`` (its URL, password hidden)."""
    from service.api.migrate import CatalogueDriverError

    if isinstance(exc, CatalogueDriverError):  # names the URL itself
        return str(exc)
    # unreachable server, bad credentials, unknown driver, a URL that is none, ...
    reason = str(getattr(exc, "orig", None) or exc).strip().splitlines()
    return f"catalogue {shown}: {reason[0] if reason else type(exc).__name__}"
