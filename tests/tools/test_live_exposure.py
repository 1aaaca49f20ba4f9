"""A live view that listens beyond loopback says so on stderr; a loopback one stays quiet.

The tests bind loopback only: the non-loopback case is reached by telling the publisher that
127.0.0.1 is not loopback, so the warning path runs without opening a port to the network.
"""
from __future__ import annotations

import logging

import pytest

from swerve.tools import live


@pytest.mark.parametrize("host, loopback", [("127.0.0.1", True), ("127.3.4.5", True), ("::1", True),
                                            ("localhost", True), ("0.0.0.0", False), ("::", False),
                                            ("192.168.1.20", False), ("robot.local", False)])
def test_loopback_hosts(host, loopback):
    assert live.is_loopback(host) is loopback


def _warnings(caplog) -> list[str]:
    return [r.getMessage() for r in caplog.records if r.name == live.__name__ and r.levelno >= logging.WARNING]


def test_a_view_beyond_loopback_warns_once(caplog, monkeypatch):
    monkeypatch.setattr(live, "is_loopback", lambda host: False)
    with caplog.at_level(logging.WARNING, logger=live.__name__), live.LivePublisher("127.0.0.1", 0) as pub:
        url = pub.url
    (msg,) = _warnings(caplog)
    assert url in msg and "reachable from other machines" in msg
    assert "no authentication" in msg and "read-only" in msg


def test_a_loopback_view_is_quiet(caplog):
    with caplog.at_level(logging.WARNING, logger=live.__name__), live.LivePublisher("127.0.0.1", 0):
        pass
    assert _warnings(caplog) == []
