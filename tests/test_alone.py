"""Tests marked `alone` run with no other test (tests/conftest.py, cpu_share): under xdist an
`alone` test waits for the tests running beside it, and the tests that come after it wait for
it, also those that asked while it waited."""

from __future__ import annotations

import threading
import time
import uuid

import pytest

from tests.conftest import ALONE_LOCKS, cpu_share, lock_path


class Holder(threading.Thread):
    """A thread that takes a CPU share (alone or not), says when it holds it, and keeps it until
    released."""

    def __init__(self, alone: bool) -> None:
        super().__init__(daemon=True)
        self.alone, self.holds, self.release = alone, threading.Event(), threading.Event()

    def run(self) -> None:
        with cpu_share(self.alone):
            self.holds.set()
            self.release.wait(30)


def test_an_alone_test_waits_for_the_others_and_the_others_wait_for_it(monkeypatch):
    run = uuid.uuid4().hex
    monkeypatch.setenv("PYTEST_XDIST_TESTRUNUID", run)
    try:
        shared = Holder(alone=False)
        shared.start()
        assert shared.holds.wait(5)
        alone = Holder(alone=True)
        alone.start()
        time.sleep(0.3)
        assert not alone.holds.is_set()  # a test still runs beside it
        later = Holder(alone=False)
        later.start()
        time.sleep(0.3)
        assert not later.holds.is_set()  # queued behind the waiting alone test
        shared.release.set()
        assert alone.holds.wait(5)
        time.sleep(0.3)
        assert not later.holds.is_set()  # nothing runs beside the alone test
        alone.release.set()
        assert later.holds.wait(5)
        later.release.set()
        for thread in (shared, alone, later):
            thread.join(5)
    finally:
        for name in ALONE_LOCKS:
            lock_path(run, name).unlink(missing_ok=True)


def test_without_xdist_there_is_no_lock(monkeypatch):
    monkeypatch.delenv("PYTEST_XDIST_TESTRUNUID", raising=False)
    with cpu_share(True), cpu_share(True):  # would deadlock on a lock
        pass
    with pytest.raises(ValueError):  # and what the test raises goes through
        with cpu_share(False):
            raise ValueError
