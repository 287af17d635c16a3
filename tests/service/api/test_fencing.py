"""Lease generations as fencing tokens in the catalogue (SQLite, and PostgreSQL in its leg)."""

from __future__ import annotations

import time
from collections.abc import Iterator

import pytest

from service.api.catalogue import Catalogue
from service.api.points import SqlPointStore
from service.studies.fence import FenceLost


@pytest.fixture
def cat(catalogue_url: str) -> Iterator[Catalogue]:
    c = Catalogue(catalogue_url)
    try:
        yield c
    finally:
        c.close()


def test_every_new_holder_gets_a_newer_token_and_a_stale_one_cannot_write(cat: Catalogue) -> None:
    cat.add_study("0123abcd45", "s", "{}", 10)
    a = cat.acquire_fenced("study:x", "a", 0.3)
    assert a == 1
    assert cat.acquire_fenced("study:x", "b", 30) is None  # alive: not b's
    assert cat.acquire_fenced("study:x", "a", 0.3) == a  # the live holder renews: same token
    time.sleep(0.4)
    b = cat.acquire_fenced("study:x", "b", 30)  # a paused past its lease: b takes over
    assert b is not None and b > a
    assert not cat.renew_fenced("study:x", "a", a, 30)  # a wakes up: its renewal fails
    assert not cat.fence_ok("study:x", "a", a) and cat.fence_ok("study:x", "b", b)
    assert not cat.update_fenced("0123abcd45", ("study:x", "a", a), points_done=9)
    assert cat.update_fenced("0123abcd45", ("study:x", "b", b), points_done=4)
    assert cat.get_study("0123abcd45")["points_done"] == 4
    # given back, then taken by anyone (even a again): newer than every earlier token
    cat.release_fenced("study:x", "b", b)
    c = cat.acquire_fenced("study:x", "a", 30)
    assert c is not None and c > b


def test_a_gone_holder_s_lease_is_taken_at_once(cat: Catalogue) -> None:
    a = cat.acquire_fenced("study:y", "a", 600)
    assert cat.acquire_fenced("study:y", "b", 600) is None
    b = cat.acquire_fenced("study:y", "b", 600, take_from="a")
    assert a is not None and b is not None and b > a


def test_point_rows_of_a_study_commit_only_under_its_current_token(cat: Catalogue) -> None:
    store = SqlPointStore(cat.engine)
    a = cat.acquire_fenced("study:0123abcd45", "a", 30)
    assert a is not None
    store.fences["0123abcd45"] = ("study:0123abcd45", "a", a)
    store.link("0123abcd45", [(0, "k" * 32)])
    cat.release_fenced("study:0123abcd45", "a", a)
    assert cat.acquire_fenced("study:0123abcd45", "b", 30) is not None
    with pytest.raises(FenceLost):
        store.link("0123abcd45", [(1, "k" * 32)])
