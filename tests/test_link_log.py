"""The link journal's times agree with each other, whatever the machine's load."""

from __future__ import annotations

import itertools

from hmi.plant.modbus import link_log
from hmi.plant.modbus.link_log import LinkLog


def _ticking_wall(monkeypatch):
    """Every read of the wall clock gives a later time, as on a loaded machine where
    milliseconds pass between two lines of code."""
    ticks = itertools.count()
    monkeypatch.setattr(link_log, "wall_now",
                        lambda: f"2026-11-25T10:00:{next(ticks):02d}.000+00:00")


def test_an_outage_is_quoted_from_the_time_its_first_problem_was_journalled(monkeypatch):
    _ticking_wall(monkeypatch)
    log = LinkLog("modbus 127.0.0.1:5020", clock=lambda: 0.0)
    for attempt in range(1, 5):
        log.connect_failed(attempt, "Connection refused")
    log.connected(5)
    failed, connected = log.drain()
    assert failed["event"] == "connect-failed" and connected["event"] == "connected"
    assert connected["failing_since"] == failed["wall"] < connected["wall"]


def test_a_loss_opens_the_outage_at_its_own_time(monkeypatch):
    _ticking_wall(monkeypatch)
    log = LinkLog("modbus 127.0.0.1:5020", clock=lambda: 0.0)
    log.connected(1)
    log.link_ok()
    log.lost("closed by the device")
    log.connect_failed(2, "Connection refused")
    entries = log.drain()
    lost = next(e for e in entries if e["event"] == "lost")
    assert log.outage is not None and log.outage.since_wall == lost["wall"]


def test_reconnected_does_not_count_the_connection_that_held(monkeypatch):
    """Every `reconnected` entry said "1 connections made that did not hold": the one that
    held was counted. Only those that then failed are."""
    _ticking_wall(monkeypatch)
    log = LinkLog("modbus 127.0.0.1:5020", clock=lambda: 0.0)
    log.connected(1)
    log.link_ok()
    log.lost("closed by the device")
    log.connected(2)
    log.link_ok()
    back = next(e for e in log.drain() if e["event"] == "reconnected")
    assert "did not hold" not in back["message"]
    assert "1 connection lost, 0 failed attempts to connect" in back["message"]
    log.lost("closed by the device")
    log.connected(3)
    log.lost("closed by the device")  # made, then dropped: did not hold
    log.connect_failed(4, "Connection refused")
    log.connected(5)
    log.link_ok()
    back = next(e for e in log.drain() if e["event"] == "reconnected")
    assert "2 connections lost, 1 failed attempt to connect, 1 connection made that did " \
        "not hold" in back["message"]
