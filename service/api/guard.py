"""Cross-site safety: the Host a request names, where a state change comes from, NUL bytes.

A page of another origin, open in the user's browser, can send requests to the service (a
form, or ``fetch`` in ``no-cors`` mode) and a DNS-rebound name can make the browser treat the
service as that page's own origin. :class:`Guard`, the outermost middleware, refuses

- a ``Host`` the service does not serve (400): ``Settings.allowed_hosts``, by default the
  loopback names (and the address it binds, when that is a specific one);
- a request that changes state (POST, PUT, PATCH, DELETE) from a page of another origin (403):
  an ``Origin`` header that is neither the service's own nor in ``Settings.allowed_origins``;
- a request that changes state without a JSON or YAML ``Content-Type`` (415), so that it can
  never be a "simple" request a browser sends cross-site without asking first (a form, or a
  ``no-cors`` fetch, can only send ``text/plain``, form types or none);
- a NUL character in the path or a query parameter (422 naming it): databases refuse it, and
  it is never part of a name, a filter or a value.
"""

from __future__ import annotations

import json
import re
from collections.abc import Awaitable, Callable
from typing import Any
from urllib.parse import parse_qsl

from service.api.settings import Settings

__all__ = ["STATE_CHANGING", "STUDY_TYPES", "Guard", "hide_paths", "host_allowed"]

#: Methods that change state: they need a JSON or YAML body type and a same-origin page.
STATE_CHANGING = frozenset({"POST", "PUT", "PATCH", "DELETE"})
#: The body types a request that changes state may declare (YAML only for study definitions;
#: the route refuses it elsewhere).
STUDY_TYPES = ("application/json", "application/yaml", "application/x-yaml", "text/yaml",
               "text/x-yaml")  # fmt: skip

ASGIApp = Callable[[dict, Callable, Callable], Awaitable[None]]

# An absolute POSIX path of two or more parts: not a URL's (no "//" or word before it), not
# one of the API's own routes (hints name them: POST /studies/{id}/resume).
_ABS_PATH = re.compile(
    r"(?<![\w/.:-])/(?!(?:studies|regressions|points|health|docs|ui)\b)(?:[\w.@+-]+/)+"
    r"([\w.@+-]+)"
)


def hide_paths(text: str | None) -> str | None:
    """``text`` with every absolute server path shown by its last part (a file's name): error
    messages the service stores and answers must not tell where its files are."""
    return None if text is None else _ABS_PATH.sub(r"\1", text)


def _hostname(host: str) -> str:
    """The name of a ``Host`` header value, without its port and brackets, lower case."""
    host = host.strip().lower()
    if host.startswith("["):  # [::1]:8000
        return host[1:].split("]", 1)[0]
    if host.count(":") == 1:
        return host.split(":", 1)[0]
    return host


def host_allowed(host: str, allowed: tuple[str, ...]) -> bool:
    """Whether the name in a ``Host`` header value is one of ``allowed`` (``*`` is any name,
    ``*.example.org`` any name under example.org)."""
    name = _hostname(host).rstrip(".")
    for pattern in allowed:
        if pattern == "*" or pattern == name:
            return True
        if pattern.startswith("*.") and name.endswith(pattern[1:]):
            return True
    return False


class Guard:
    """The checks of this module, before any route (and before the body is read)."""

    def __init__(self, app: ASGIApp, settings: Callable[[], Settings]) -> None:
        self.app = app
        self.settings = settings

    async def __call__(self, scope: dict, receive: Callable, send: Callable) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        refusal = self.refusal(scope)
        if refusal is None:
            await self.app(scope, receive, send)
            return
        status, body = refusal
        data = json.dumps(body).encode()
        await send({"type": "http.response.start", "status": status,
                    "headers": [(b"content-type", b"application/json"),
                                (b"content-length", str(len(data)).encode())]})  # fmt: skip
        await send({"type": "http.response.body", "body": data})

    def refusal(self, scope: dict) -> tuple[int, dict[str, Any]] | None:
        """The status and body refusing this request, or None to let it through."""
        settings = self.settings()
        headers = {k.decode("latin-1").lower(): v.decode("latin-1")
                   for k, v in scope.get("headers", [])}  # fmt: skip
        host = headers.get("host")
        if host is not None and not host_allowed(host, settings.host_names()):
            return 400, {
                "detail": f"Host {host[:100]!r} is not one this service answers to (allowed: "
                f"{', '.join(settings.host_names())}; set IMPACTCELL_ALLOWED_HOSTS to add names)"
            }
        nul = _nul_problems(scope)
        if nul:
            detail = "; ".join(f"{p['path']}: {p['message']}" for p in nul)
            return 422, {"detail": detail, "problems": nul}
        if scope["method"] not in STATE_CHANGING:
            return None
        origin = headers.get("origin")
        if origin is not None:
            own = f"{scope.get('scheme', 'http')}://{host}".lower() if host else None
            given = origin.strip().lower().rstrip("/")
            if given != own and given not in settings.origins():
                return 403, {
                    "detail": f"{scope['method']} from a page of another origin refused: Origin "
                    f"{origin[:100]!r} is not this service's own ({own}) nor one of "
                    "IMPACTCELL_ALLOWED_ORIGINS"
                }
        kind = headers.get("content-type", "").split(";")[0].strip().lower()
        if kind not in STUDY_TYPES:
            got = repr(kind) if kind else "none"
            return 415, {
                "detail": f"a {scope['method']} request must declare a JSON or YAML body "
                f"(Content-Type: application/json, also with no body; application/yaml for a "
                f"study definition); got Content-Type {got}"
            }
        return None


def _nul_problems(scope: dict) -> list[dict[str, str]]:
    """A problem for the path and for each query parameter holding a NUL character."""
    problems = []
    if "\x00" in scope.get("path", ""):
        problems.append({"path": "path", "message": "must not contain a NUL character"})
    query = scope.get("query_string", b"").decode("latin-1")
    if "%00" in query or "\x00" in query:
        for name, value in parse_qsl(query, keep_blank_values=True):
            if "\x00" in name or "\x00" in value:
                shown = name.replace("\x00", "\\x00")[:64]
                problems.append(
                    {"path": f"query.{shown}", "message": "must not contain a NUL character"}
                )
        if not problems:  # in a part parse_qsl drops (no "="): name the raw text
            problems.append({"path": "query", "message": "must not contain a NUL character"})
    return problems
