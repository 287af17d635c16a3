"""service.client on its own (an httpx mock transport, no service): waiting and progress."""

from __future__ import annotations

from typing import Any

import httpx
import pytest

from service.client import Client, NotFound, StudyFailed


def _client(statuses: list[str], total: int = 10) -> Client:
    """A client whose study ``abc123`` goes through ``statuses``, one per poll."""
    polls = iter(statuses)

    def handler(request: httpx.Request) -> httpx.Response:
        if request.url.path != "/studies/abc12345":
            return httpx.Response(404, json={"detail": f"no study {request.url.path}"})
        status = next(polls)
        done = total if status == "finished" else total // 2
        return httpx.Response(200, json={
            "id": "abc12345", "name": "mock", "status": status, "points_total": total,
            "points_done": done, "error": "boom" if status == "failed" else None,
        })  # fmt: skip

    return Client("http://mock", token="", transport=httpx.MockTransport(handler))


def test_wait_draws_a_progress_line_on_stderr(capsys: pytest.CaptureFixture[str]) -> None:
    rec = _client(["running", "finished"]).wait("abc12345", poll=0)
    assert rec["status"] == "finished"
    err = capsys.readouterr().err
    assert "mock:  50.0% 5/10 pt [running]" in err
    assert err.endswith("mock: 100.0% 10/10 pt [finished]\n")


def test_wait_feeds_a_progress_callable_or_nothing(capsys: pytest.CaptureFixture[str]) -> None:
    seen: list[dict[str, Any]] = []
    _client(["queued", "running", "finished"]).wait("abc12345", progress=seen.append, poll=0)
    assert [r["status"] for r in seen] == ["queued", "running", "finished"]
    _client(["running", "finished"]).wait("abc12345", progress=False, poll=0)
    assert capsys.readouterr().err == ""


def test_wait_raises_for_a_failed_study_and_errors_by_status() -> None:
    with pytest.raises(StudyFailed, match="ended failed: boom"):
        _client(["running", "failed"]).wait("abc12345", progress=False, poll=0)
    with pytest.raises(NotFound, match="no study"):
        _client([]).get("ffff0000")
