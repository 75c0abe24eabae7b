"""A query's answer is hostile input too: a foreign peer's queryable on a run's key, answering
with garbage, neither hides the real answer nor stops a process from joining (SPEC 5)."""

from __future__ import annotations

import logging
import socket
import time
from collections.abc import Iterator
from typing import Any

import pytest
import zenoh

from swarm.net.keys import Keys
from swarm.net.zconfig import ZenohOptions
from swarm.procs.robot_status import fetch_config
from swarm.procs.runconfig import RunRecord
from world.config import WorldConfig

GARBAGE = [b"\xff\xfe", b"", b"\x93\x01\x02\x03", b"\x81\xa5world\xa3bad"]


def _port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@pytest.fixture
def hub() -> Iterator[tuple[str, zenoh.Session]]:
    """A listening session on a free loopback port (multicast scouting off)."""
    ep = f"tcp/127.0.0.1:{_port()}"
    with zenoh.open(ZenohOptions(listen=[ep]).to_config()) as s:
        yield ep, s


def _foreign(ep: str, key: str) -> tuple[zenoh.Session, object]:
    """A foreign peer answering `key` with every payload of GARBAGE."""
    s = zenoh.open(ZenohOptions(connect=[ep]).to_config())

    def answer(q: zenoh.Query) -> None:
        for junk in GARBAGE:
            q.reply(key, junk)
    return s, s.declare_queryable(key, answer)


def test_a_garbage_answer_on_the_config_key_neither_hides_nor_replaces_the_worlds(
        hub: tuple[str, zenoh.Session], caplog: pytest.LogCaptureFixture) -> None:
    """With Zenoh's default consolidation a client saw only the foreign reply (one per key),
    and the first reply it saw, unreadable, stopped it: `swarm robot`, `record`, `fault`,
    `audit` all exited with "not msgpack". Every reply is now read and the world's is taken."""
    ep, world = hub
    keys = Keys("q1")
    rec = RunRecord(world=WorldConfig(n_robots=3))

    def answer(q: zenoh.Query) -> None:
        time.sleep(0.3)  # the foreign peer's garbage comes first
        q.reply(keys.config, rec.pack())
    world.declare_queryable(keys.config, answer)
    foreign, _ = _foreign(ep, keys.config)
    try:
        with zenoh.open(ZenohOptions(connect=[ep]).to_config()) as client:
            time.sleep(0.5)  # both queryables known to the client's router
            with caplog.at_level(logging.WARNING, "swarm.inbox"):
                got = [fetch_config(client, keys, 10.0) for _ in range(3)]
    finally:
        foreign.close()
    assert all(g.world == rec.world for g in got)
    assert "dropped an unreadable reply on swarm/q1/world/config" in caplog.text


def test_only_garbage_is_a_one_line_timeout_that_counts_what_was_dropped(
        hub: tuple[str, zenoh.Session]) -> None:
    ep, _ = hub
    keys = Keys("q2")
    foreign, _ = _foreign(ep, keys.config)
    try:
        with zenoh.open(ZenohOptions(connect=[ep]).to_config()) as client:
            time.sleep(0.5)
            with pytest.raises(TimeoutError) as exc:
                fetch_config(client, keys, 1.5)
    finally:
        foreign.close()
    msg = str(exc.value)
    assert "\n" not in msg and msg.startswith(f"no world answered on {keys.config} within 1.5 s (")
    assert "unreadable replies dropped; the last: run record from" in msg, msg


@pytest.mark.parametrize("settle", [0.0, 2.0])
def test_an_id_taken_while_a_robot_joins_is_refused_only_with_a_settle_window(
        hub: tuple[str, zenoh.Session], settle: float) -> None:
    """A peer reaches the robot holding its id only once gossip linked them, maybe after its
    first liveliness query (CI: a duplicate robot 1 joined a run): `check_free` asks again until
    its settle window since the session opened has passed. A token that comes 0.5 s after the
    newcomer's session opened is seen with the robot's window and missed with none."""
    import threading

    from swarm.net.inbox import check_free
    from world.config import ConfigError

    ep, _ = hub
    key = Keys("claim").alive_robot(1)
    holder: list[Any] = []  # the holder's session and token (a dropped token is undeclared)

    def take_later() -> None:
        time.sleep(0.5)
        s = zenoh.open(ZenohOptions(connect=[ep]).to_config())
        holder.extend([s, s.liveliness().declare_token(key)])

    with zenoh.open(ZenohOptions(connect=[ep]).to_config()) as newcomer:
        opened = time.monotonic()
        later = threading.Thread(target=take_later)
        later.start()
        try:
            if settle:
                with pytest.raises(ConfigError, match="running already"):
                    check_free(newcomer, key, "robot 1 of run claim", since=opened, settle=settle)
            else:
                check_free(newcomer, key, "robot 1 of run claim", since=opened, settle=settle)
        finally:
            later.join()
            if holder:
                holder[0].close()
