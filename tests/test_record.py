"""Recordings (issue 15): a real run recorded into MCAP, read back with the `mcap` reader,
verified, tampered with, replayed into a capture console, traced; the attention field (the
command-line cases: test_record_cli.py)."""

from __future__ import annotations

import io
import json
import signal
from collections import Counter
from pathlib import Path
from typing import Any

import pytest
from conftest import ROOT, swarm

mcap = pytest.importorskip("mcap")  # the `record` extra (in `test` too)

from rich.console import Console  # noqa: E402

from swarm.net.keys import Keys  # noqa: E402
from swarm.net.messages import (  # noqa: E402
    K_RESULT,
    K_RSTATUS,
    K_STATUS,
    Action,
    BadMessage,
    Bundle,
    Hidden,
    Obs,
    Traj,
    pack_record,
    unpack_record,
)
from swarm.net.record import msgjson  # noqa: E402
from swarm.net.record.recording import RecordingWriter  # noqa: E402
from swarm.net.records import check_robot_status  # noqa: E402
from swarm.procs.dashboard import SwarmView, render  # noqa: E402
from swarm.procs.runconfig import RunConfig, RunRecord  # noqa: E402
from world.config import WorldConfig  # noqa: E402

CKPT = str(ROOT / "checkpoints" / "commattn.pt")
ROBOTS, HORIZON = 3, 8


# ------------------------------------------------------------------------------------ helpers
def check_schema(obj: Any, schema: dict[str, Any], where: str = "$") -> None:
    """A tiny JSON Schema validator: type (one, or a list of them), properties, required,
    additionalProperties, items."""
    t = schema.get("type")
    if isinstance(t, list):
        if obj is None:
            assert "null" in t, f"{where}: null is not {t}"
            return
        t = next(k for k in t if k != "null")
        schema = {**schema, "type": t}
    types = {"object": dict, "array": list, "string": str, "boolean": bool}
    if t in types:
        assert isinstance(obj, types[t]), f"{where}: {obj!r} is not {t}"
    elif t == "integer":
        assert isinstance(obj, int) and not isinstance(obj, bool), f"{where}: not an integer"
    elif t == "number":
        assert isinstance(obj, (int, float)) and not isinstance(obj, bool), f"{where}: not a number"
    if t == "object":
        for key in schema.get("required", []):
            assert key in obj, f"{where}: missing {key}"
        props, extra = schema.get("properties", {}), schema.get("additionalProperties", True)
        for key, value in obj.items():
            if key in props:
                check_schema(value, props[key], f"{where}.{key}")
            elif isinstance(extra, dict):
                check_schema(value, extra, f"{where}.{key}")
            else:
                assert extra, f"{where}: unexpected {key}"
    if t == "array" and "items" in schema:
        for k, value in enumerate(obj):
            check_schema(value, schema["items"], f"{where}[{k}]")


def read_mcap(path: Path) -> tuple[dict[str, Any], list[tuple[str, str, bytes, Any]]]:
    """With the `mcap` package alone: summary, metadata, (topic, encoding, data, schema)s."""
    from mcap.reader import make_reader

    with open(path, "rb") as fh:
        reader = make_reader(fh)
        summary = reader.get_summary()
        msgs = [(ch.topic, ch.message_encoding, bytes(m.data), sc)
                for sc, ch, m in reader.iter_messages(log_time_order=False)]
        fh.seek(0)
        meta = {md.name: dict(md.metadata) for md in make_reader(fh).iter_metadata()}
    return {"summary": summary, "meta": meta}, msgs


def rewrite(src: Path, dst: Path, edit_msg: Any = None, edit_meta: Any = None,
            rename: Any = None, chunk_size: int = 1024 * 1024, in_time: bool = False) -> None:
    """Copy a recording with the mcap reader and writer, editing messages, metadata or topics;
    `in_time`: messages in log-time order (a JSON form beside its raw payload), else as filed."""
    from mcap.reader import make_reader
    from mcap.writer import Writer

    with open(src, "rb") as fh, open(dst, "wb") as out:
        reader = make_reader(fh)
        summ = reader.get_summary()
        w = Writer(out, chunk_size=chunk_size)
        w.start(profile=reader.get_header().profile, library="test")
        fh.seek(0)
        for md in make_reader(fh).iter_metadata():
            w.add_metadata(md.name, (edit_meta or (lambda n, d: d))(md.name, dict(md.metadata)))
        fh.seek(0)
        for a in make_reader(fh).iter_attachments():
            if a.name == "run_record.json":
                w.add_attachment(a.create_time, a.log_time, a.name, a.media_type, a.data)
        sids = {i: w.register_schema(s.name, s.encoding, s.data) for i, s in summ.schemas.items()}
        cids = {i: w.register_channel((rename or (lambda t: t))(c.topic), c.message_encoding,
                                      sids.get(c.schema_id, 0), c.metadata)
                for i, c in summ.channels.items()}
        fh.seek(0)
        for _, ch, m in make_reader(fh).iter_messages(log_time_order=in_time):
            data = (edit_msg or (lambda t, d: d))(ch.topic, bytes(m.data))
            if data is None:  # (the edit deletes it)
                continue
            w.add_message(cids[m.channel_id], m.log_time, data, m.publish_time, m.sequence)
        fh.seek(0)  # (but the run record, after the messages, as the recorder files them)
        for a in make_reader(fh).iter_attachments():
            if a.name != "run_record.json":
                w.add_attachment(a.create_time, a.log_time, a.name, a.media_type, a.data)
        w.finish()


def synthetic(path: Path, run_id: str = "syn", robots: int = 2,
              bad_status_at: tuple[int, ...] = ()) -> None:
    """A small well-formed recording written in-process (no swarm run); with `bad_status_at`,
    an unreadable robot status (a foreign peer's) after the observations of those ticks."""
    cfg = WorldConfig(n_robots=robots, horizon=4)
    rec = RunRecord(cfg, RunConfig(run_id=run_id, episodes=1)).to_record()
    w = RecordingWriter(path, run_id, rec, cfg, "virtual", 2.0)
    keys = Keys(run_id)
    for t in range(3):
        for i in range(robots):
            p = Obs(0, t, i, 1, i, bytes(cfg.vision ** 2), 0.0, False, 100.0).pack()
            w.message(keys.obs(i), "obs", p, w.decode(keys.obs(i), "obs", p)[1], 10**18 + t, t, 0)
        if t in bad_status_at:
            w.message(keys.robot_status(0), "rstatus", b"\xff", None, 10**18 + t, t, 0)
    w.finish(None, {})


def swarm_main(*args: str, capsys: Any) -> tuple[int, str]:
    """`swarm ARGS` in-process (fast): exit status and stderr; pytest's SIGTERM handler kept."""
    from swarm.cli import main

    handler = signal.getsignal(signal.SIGTERM)
    try:
        code = main(list(args))
    finally:
        signal.signal(signal.SIGTERM, handler)
    err = capsys.readouterr().err.strip()
    return code, err


# ---------------------------------------------------------------- a recorded CommAttn run
@pytest.fixture(scope="module")
def recorded(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    d = tmp_path_factory.mktemp("rec")
    f, res = d / "run.mcap", d / "run.json"
    r = swarm("run", "--headless", "--robots", str(ROBOTS), "--policy", "commattn",
              "--checkpoint", CKPT, "--episodes", "1", "--horizon", str(HORIZON), "--seed", "7",
              "--loss", "0.3", "--comm-range", "6", "--run-id", "rec15", "--record", str(f),
              "--json", str(res), "--log-dir", str(d / "logs"), timeout=120)
    assert r.returncode == 0, r.stderr[-2000:]
    return {"dir": d, "file": f, "result": json.loads(res.read_text())}


@pytest.mark.procs
def test_a_recorded_run_reads_back_with_the_mcap_reader(recorded: dict[str, Any]) -> None:
    info, msgs = read_mcap(recorded["file"])
    res, keys = recorded["result"], Keys("rec15")
    assert res["recording"]["exit"] == 0
    assert info["meta"]["swarm.recording"]["run_id"] == "rec15"
    assert info["meta"]["swarm.recorder"]["ended"] == "end"
    raw = Counter(keys.kind_of(t)[0] for t, enc, _, _ in msgs if enc == "msgpack")
    # every key kind of a chained run, raw and as JSON
    for kind in ("obs", "traj", "bundle", "hidden", "radio_hidden", "action", "status",
                 "rstatus", "result", "end"):
        assert raw[kind] > 0, kind
    topics = {c.topic for c in info["summary"].channels.values()}
    for i in range(ROBOTS):
        for key in (keys.obs(i), keys.traj(i), keys.hidden(i), keys.action(i), keys.inbox(i),
                    keys.robot_status(i)):
            assert key in topics and key + "/json" in topics
    # message counts are the run's own counters
    ticks, m = res["ticks"], res["messages"]
    assert raw["status"] == ticks and raw["action"] == ticks * ROBOTS
    assert raw["traj"] == m["traj_in"] and raw["hidden"] == m["hidden_in"]
    assert raw["bundle"] == ticks * ROBOTS and raw["obs"] == (ticks + 1) * ROBOTS
    cfg = WorldConfig(n_robots=ROBOTS, horizon=HORIZON, comm_range=6)
    bundles = [Bundle.unpack(d, cfg) for t, e, d, _ in msgs
               if e == "msgpack" and keys.kind_of(t)[0] == "bundle"]
    assert sum(len(b.trajs) for b in bundles) == m["traj_delivered"]
    hiddens = [Hidden.unpack(d, cfg) for t, e, d, _ in msgs
               if e == "msgpack" and keys.kind_of(t)[0] == "radio_hidden"]
    assert sum(not h.is_miss for h in hiddens) == m["hidden_delivered"]
    # each robot's own counters (its final status) against what was recorded from and to it:
    # what it sent exactly; what it received at most what was sent to it (Zenoh's default
    # congestion control drops a put on a congested link, and the recorder has a link of its own)
    last: dict[int, dict[str, Any]] = {}
    for t, e, d, _ in msgs:
        if e == "json" and keys.kind_of(t.removesuffix("/json"))[0] == "rstatus":
            rec = json.loads(d)
            if rec["msgs_out"] >= last.get(rec["robot"], {}).get("msgs_out", -1):
                last[rec["robot"]] = rec
    per = Counter(keys.kind_of(t) for t, e, _, _ in msgs if e == "msgpack")
    for i in range(ROBOTS):
        assert last[i]["msgs_out"] == per[("traj", i)] + per[("hidden", i)] + per[("action", i)]
        sent_to = per[("obs", i)] + per[("bundle", i)] + per[("radio_hidden", i)]
        assert sent_to - 2 <= last[i]["msgs_in"] <= sent_to
    # raw payloads are bit-exact: every trajectory message is inside the bundles verbatim
    in_bundles = {p for b in bundles for p in b.trajs}
    trajs = [d for t, e, d, _ in msgs if e == "msgpack" and keys.kind_of(t)[0] == "traj"]
    assert in_bundles <= set(trajs) and len(in_bundles) == len(trajs)


@pytest.mark.procs
def test_json_channels_validate_against_their_schemas(recorded: dict[str, Any]) -> None:
    _, msgs = read_mcap(recorded["file"])
    n = 0
    for topic, enc, data, schema in msgs:
        if enc != "json":
            continue
        assert schema is not None and schema.encoding == "jsonschema", topic
        check_schema(json.loads(data), json.loads(schema.data), topic)
        n += 1
    assert n > 100


@pytest.mark.procs
def test_commattn_statuses_carry_attention_over_the_members_heard(recorded: dict) -> None:
    """Checked whenever the policy reports `last_attention` (CommAttn does): weights over the
    members each robot heard at that tick, zero elsewhere, summing to 1."""
    from swarm.common import policy_spec

    cfg = WorldConfig(n_robots=ROBOTS, horizon=HORIZON, comm_range=6)
    build = getattr(policy_spec, "build_inference", policy_spec.build_policy)
    reports = hasattr(build("commattn", cfg, CKPT), "last_attention")
    _, msgs = read_mcap(recorded["file"])
    keys = Keys("rec15")
    heard = {}
    attn = []
    for topic, enc, data, _ in msgs:
        kind = keys.kind_of(topic.removesuffix("/json"))[0]
        if enc == "json" and kind == "bundle":
            b = json.loads(data)
            heard[(b["ep"], b["t"], b["robot"])] = set(b["senders"])
        elif enc == "json" and kind == "rstatus" and "attn" in (s := json.loads(data)):
            attn.append(s)
    if not reports:
        pytest.skip("this build's CommAttn does not report last_attention yet")
    assert len(attn) >= 2 * ROBOTS  # headless: with the counters every 5 ticks, and at the end
    for s in attn:
        w = s["attn"]
        assert sum(w) == pytest.approx(1.0, abs=1e-3)
        members = heard[(s["ep"], s["attn_t"], s["robot"])]
        assert all(x == 0 for j, x in enumerate(w) if j not in members), s
        assert s["robot"] in members


@pytest.mark.procs
def test_verify_passes_and_names_the_tick_of_an_altered_action(recorded: dict[str, Any],
                                                                tmp_path: Path) -> None:
    r = swarm("replay", str(recorded["file"]), "--verify", "--json", str(tmp_path / "v.json"))
    assert r.returncode == 0, r.stderr
    v = json.loads((tmp_path / "v.json").read_text())
    assert v["ok"] and v["checked"]["statuses"] == HORIZON and v["checked"]["bundles"] > 0
    assert v["checked"]["hidden forwarded"] > 0 and v["checked"]["results"] == 1
    cfg = WorldConfig(n_robots=ROBOTS, horizon=HORIZON)
    target = ("swarm/rec15/robot/1/action", 4)

    def alter(topic: str, data: bytes) -> bytes:
        if topic == target[0]:
            a = Action.unpack(data, cfg)
            if a.t == target[1]:
                return Action(a.ep, a.t, a.robot, (a.action + 4) % 9, a.planning_ms).pack()
        return data

    bad = tmp_path / "altered.mcap"
    rewrite(recorded["file"], bad, edit_msg=alter)
    r = swarm("replay", str(bad), "--verify")
    assert r.returncode == 1
    line = r.stderr.strip().splitlines()[-1]
    assert "divergence at episode 0 tick 4 (run tick 4)" in line and "recorded" in line, line
    # the world/result message on the wire is checked too, against the recorder's copy (UA
    # pass: a forged elratio there verified clean)

    def forge(topic: str, data: bytes) -> bytes:
        if topic == "swarm/rec15/world/result":
            rec = unpack_record(data, K_RESULT)
            return pack_record(K_RESULT, {**rec, "elratio_mean": 0.99})
        return data

    rewrite(recorded["file"], bad, edit_msg=forge)
    r = swarm("replay", str(bad), "--verify")
    assert r.returncode == 1 and "(run tick 8): result.json (the recorder's copy, as recorded) " \
        "against the world/result message (as recomputed): recorded {'elratio_mean'" \
        in r.stderr, r.stderr
    # a file that lost only its closing magic is not whole: --partial is needed for it
    bare = tmp_path / "bare.mcap"
    bare.write_bytes(recorded["file"].read_bytes()[:-1])
    r = swarm("replay", str(bare), "--verify")
    assert r.returncode == 2 and "is truncated" in r.stderr, r.stderr
    # a recording cut after the run (its summary lost) verifies whole with --partial: the
    # result in it says the run ended, so its last tick is complete (it was a false divergence)
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(recorded["file"].read_bytes()[:-20])
    r = swarm("replay", str(cut), "--partial", "--verify")
    assert r.returncode == 0 and "every one as recorded" in r.stdout, r.stdout + r.stderr
    # a file with a hole in it is no pass, even with --partial (it passed on the ticks before)
    from mcap.reader import make_reader

    small = tmp_path / "small.mcap"  # (chunks of 4 kB, however the recorder's flushes fell)
    rewrite(recorded["file"], small, chunk_size=4096, in_time=True)
    data = bytearray(small.read_bytes())
    with open(small, "rb") as fh:  # inside a chunk a third in: whole ticks before it
        chunks = sorted(make_reader(fh).get_summary().chunk_indexes,
                        key=lambda c: c.chunk_start_offset)
    at = chunks[len(chunks) // 3].chunk_start_offset + 100
    data[at:at + 200] = bytes(b ^ 0xFF for b in data[at:at + 200])
    holed = tmp_path / "holed.mcap"
    holed.write_bytes(bytes(data))
    r = swarm("replay", str(holed), "--partial", "--verify", "--json", str(tmp_path / "h.json"))
    line = r.stderr.strip().splitlines()[-1]
    assert r.returncode == 1 and line.startswith(f"swarm: verify: {holed}: damaged at bytes ") \
        and "ticks before it are as recorded" in line, r.stdout + r.stderr
    first, last = map(int, line.split(" at bytes ")[1].split(" of ")[0].split("-"))
    assert first <= at < last, line  # (the chunk that holds the flipped bytes, not its end)
    h = json.loads((tmp_path / "h.json").read_text())  # (its JSON said ok: true)
    assert h["damaged"] and not h["ok"], h


@pytest.mark.procs
def test_verify_checks_every_json_form_against_the_raw_payload_beside_it(
        recorded: dict[str, Any], tmp_path: Path) -> None:
    """UA pass: --verify never read the `/json` channels (what MCAP tools and Foxglove show), so
    a file whose JSON forms were edited verified as "every one as recorded"."""
    r = swarm("replay", str(recorded["file"]), "--verify", "--json", str(tmp_path / "v.json"))
    assert r.returncode == 0 and json.loads((tmp_path / "v.json").read_text())["checked"][
        "JSON forms"] > ROBOTS * HORIZON * 3, r.stderr  # (obs, action, status, ... of each tick)

    def action(topic: str, data: bytes) -> bytes:  # one action + 4, in its JSON form only
        obj = json.loads(data) if topic == "swarm/rec15/robot/2/action/json" else {}
        if obj.get("t") == 3:
            return json.dumps({**obj, "action": (obj["action"] + 4) % 9}).encode()
        return data

    def elratio(topic: str, data: bytes) -> bytes:  # every status's, in its JSON form only
        if topic == "swarm/rec15/world/status/json":
            return json.dumps({**json.loads(data), "elratio": 0.999}).encode()
        return data

    def stray(topic: str, data: bytes) -> bytes:  # a form put on another key's channel
        return data.replace(b'"robot":1', b'"robot":0') if topic.endswith("robot/1/action/json") \
            else data

    def deleted(topic: str, data: bytes) -> bytes | None:  # one form gone: named as missing,
        obj = json.loads(data) if topic == "swarm/rec15/robot/2/action/json" else {}
        return None if obj.get("t") == 3 else data  # not as the next one's changed field

    bad = tmp_path / "edited.mcap"
    for edit, said in ((action, "episode 0 tick 3 (run tick 3): swarm/rec15/robot/2/action/json "
                                "action (the JSON form of the raw payload beside it): recorded"),
                       (elratio, "episode 0 tick 1 (run tick 1): swarm/rec15/world/status/json "
                                 "elratio (the JSON form of the raw payload beside it): recorded "
                                 "0.999, recomputed"),
                       (stray, "swarm/rec15/robot/1/action/json robot (the JSON form of the raw "
                               "payload beside it): recorded 0, recomputed 1"),
                       (deleted, "episode 0 tick 3 (run tick 3): swarm/rec15/robot/2/action/json "
                                 "(no JSON form of the raw payload beside it)")):
        rewrite(recorded["file"], bad, edit_msg=edit)
        r = swarm("replay", str(bad), "--verify")
        line = r.stderr.strip().splitlines()[-1]
        assert r.returncode == 1 and said in line, line


@pytest.mark.procs
def test_verify_reruns_direct_delivery_and_names_a_false_stamp(tmp_path: Path) -> None:
    """A direct-delivery run under loss, latency, a bandwidth cap and a partition: every robot's
    decisions re-run from the recorded stamped messages give the counters it reported; a stamp
    whose queue delay its sender's bucket does not give is named."""
    from swarm.net.messages import K_TRAJ, Stamped

    f = tmp_path / "direct.mcap"
    r = swarm("run", "--headless", "--robots", "4", "--policy", "commattn", "--checkpoint", CKPT,
              "--episodes", "2", "--horizon", str(HORIZON), "--seed", "3", "--delivery", "direct",
              "--loss", "0.2", "--latency", "120ms", "--jitter", "60ms", "--bandwidth",
              "1.5kB/s", "--partition", "0-1/2-3", "--tick-timeout", "0.2", "--run-id", "recd",
              "--record", str(f), timeout=120)
    assert r.returncode == 0, r.stderr[-2000:]
    r = swarm("replay", str(f), "--verify", "--json", str(tmp_path / "v.json"))
    assert r.returncode == 0, r.stderr
    v = json.loads((tmp_path / "v.json").read_text())
    assert v["ok"] and v["checked"]["direct copies decided"] > 0 and v["checked"]["results"] == 1
    cfg = WorldConfig(n_robots=4, horizon=HORIZON)

    def alter(topic: str, data: bytes) -> bytes:
        if topic == "swarm/recd/robot/2/dtraj":
            st = Stamped.unpack(data, cfg)
            if (st.ep, st.t) == (1, 3) and st.kind == K_TRAJ:
                return Stamped(st.kind, st.ep, st.t, st.robot, st.queue_ms + 250.0,
                               st.payload).pack()
        return data

    bad = tmp_path / "altered.mcap"
    rewrite(f, bad, edit_msg=alter)
    r = swarm("replay", str(bad), "--verify")
    assert r.returncode == 1
    line = r.stderr.strip().splitlines()[-1]
    assert "divergence at episode 1 tick 3" in line and "robot 2's trajectory stamp" in line, line

    # whom each robot heard comes with its action (the dashboard's links), checked the same way
    _, msgs = read_mcap(f)
    links = [json.loads(d)["heard_links"] for topic, _, d, _ in msgs
             if topic == f"{Keys('recd').status}/json"]
    assert max(links) > 0

    def claim(topic: str, data: bytes) -> bytes:
        if topic == Keys("recd").action(1):
            a = Action.unpack(data, cfg)
            if (a.ep, a.t) == (0, 5):
                return Action(a.ep, a.t, a.robot, a.action, a.planning_ms, a.bucket,
                              bytes([0b11110000])).pack()  # "it heard everyone"
        return data

    rewrite(f, bad, edit_msg=claim)
    r = swarm("replay", str(bad), "--verify")
    line = r.stderr.strip().splitlines()[-1]
    assert r.returncode == 1 and "episode 0 tick 5" in line and "robot 1's heard" in line, line


@pytest.mark.procs
def test_a_robot_restarted_under_direct_delivery_verifies(tmp_path: Path) -> None:
    """A robot killed and restarted in a direct-delivery run under a tight bandwidth cap: its
    successor takes up the token bucket its last action reported, its peers do not wait for it
    once its token is gone, and the world adds both incarnations' counts; so the re-run of every
    robot's deliveries from the recording (one link per robot, never restarted) agrees with
    every stamp and with the result, less what the dead one counted after its last report."""
    f = tmp_path / "restart.mcap"
    r = swarm("run", "--headless", "--robots", "4", "--policy", "nearest-frontier",
              "--episodes", "3", "--seed", "3", "--delivery", "direct", "--bandwidth", "200B/s",
              "--loss", "0.2", "--tick-timeout", "0.2", "--crash", "1@3",
              "--restart", "1@6", "--pace", "20", "--run-id", "rest", "--record", str(f),
              "--json", str(tmp_path / "r.json"), timeout=120)
    assert r.returncode == 0, r.stderr[-2000:]
    res = json.loads((tmp_path / "r.json").read_text())
    assert res["robot_restarts"] == 1 and res["completed"] == 3
    assert [e["robot"] for e in res["messages"]["restarted"]] == [1]
    _, msgs = read_mcap(f)
    taken = [json.loads(data)["bucket"] for topic, enc, data, _ in msgs
             if topic == f"{Keys('rest').obs(1)}/json" and b"bucket" in data]
    assert taken and min(b[0] for b in taken) < 0  # it came back owing bytes
    r = swarm("replay", str(f), "--verify", "--json", str(tmp_path / "v.json"))
    assert r.returncode == 0, r.stderr
    v = json.loads((tmp_path / "v.json").read_text())
    assert v["ok"] and v["checked"]["direct copies decided"] > 0
    from swarm.studies.replay import load, replay

    view, _ = replay(load(f), Console(file=io.StringIO()), speed=0)  # the run's own process
    assert view.events == res["process_faults"]  # faults, as the live dashboard showed them


@pytest.mark.procs
def test_a_robot_hung_to_the_end_under_direct_delivery_verifies(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The world sums a hung robot's counts to its last report, which came before its last
    tick; the audit summed its link to that tick, a false divergence of result.messages
    (review helper 92; a crash without a restart the same). It counts to the report now."""
    from conftest import swarm_here

    f = tmp_path / "hang.mcap"
    r = swarm("run", "--headless", "--robots", "4", "--policy", "commattn", "--episodes", "2",
              "--horizon", "10", "--size", "10x10", "--loss", "0.2", "--delivery", "direct",
              "--hang", "2@12", "--record", str(f), timeout=120)
    assert r.returncode == 0, r.stderr[-2000:]
    r = swarm_here("replay", str(f), "--verify", capsys=capsys)
    assert r.returncode == 0, r.stderr


@pytest.mark.procs
def test_replay_of_a_training_run_shows_the_learner_panel(tmp_path: Path) -> None:
    """A `--train` run's recording holds the learner's statuses; its replay drew no learner
    panel (the live dashboard does)."""
    from swarm.studies.replay import load, replay

    f = tmp_path / "train.mcap"
    r = swarm("run", "--headless", "--train", "--robots", "3", "--episodes", "3", "--horizon",
              "10", "--policy", "commattn", "--train-batch", "2", "--record", str(f),
              "--learner-out", str(tmp_path / "learner"), timeout=180)
    assert r.returncode == 0, r.stderr[-2000:]
    console = Console(file=io.StringIO(), width=180, record=True, color_system=None)
    view, stats = replay(load(f), console, speed=0)
    assert stats.bad == 0 and view.learner is not None and view.learner["version"] >= 1
    assert "learner" in console.export_text()


@pytest.mark.procs
def test_replay_renders_the_run_into_a_capture_console(recorded: dict[str, Any]) -> None:
    from swarm.studies.replay import load, replay

    console = Console(file=io.StringIO(), width=180, record=True, color_system=None)
    view, stats = replay(load(recorded["file"]), console, speed=0)
    text = console.export_text()
    assert "map 20x20" in text and "rec15" in text and "commattn" in text
    assert f"{recorded['result']['elratio_mean']:.3f}" in text  # the last status's elratio
    assert stats.statuses == HORIZON and stats.bad == 0
    if view.attention:  # CommAttn robots reported attention: the table and the map show it
        assert "attention (strongest)" in text
    r = swarm("replay", str(recorded["file"]), "--speed", "0", "--from", "3", "--until", "5")
    assert r.returncode == 0 and "replayed" in r.stdout and "ticks 3..5" in r.stdout


@pytest.mark.procs
def test_trace_writes_tables_and_figures(recorded: dict[str, Any]) -> None:
    out = recorded["dir"] / "trace"
    r = swarm("trace", str(recorded["file"]), "--out", str(out))
    assert r.returncode == 0, r.stderr
    for name in ("links.csv", "robots.csv", "kinds.csv", "elratio.csv", "links.png",
                 "latency.png", "elratio.png"):
        assert (out / name).stat().st_size > 0, name
    import csv

    links = list(csv.DictReader(open(out / "links.csv")))
    m = recorded["result"]["messages"]
    own = recorded["result"]["ticks"] * ROBOTS  # each robot's own message, in every bundle
    assert sum(int(x["delivered_traj"]) for x in links) == m["traj_delivered"] - own \
        == m["traj_to_others"]  # (the experiment CSV's `delivered`)
    assert sum(int(x["dropped_both_kinds"]) for x in links) == m["lost"]  # both kinds
    col = {k: sum(int(x[k]) for x in links) for k in ("delivered_hidden", "hidden_miss_sender",
                                                        "hidden_miss_radio")}
    # a hidden-state forward carries a state, the sender's word that it had none (delivered
    # copies both), or the radio's word in place of a copy the loss took
    assert col["delivered_hidden"] + col["hidden_miss_sender"] == m["hidden_delivered"]
    assert col["hidden_miss_radio"] == m["by_kind"]["hidden"]["lost"] > 0
    kinds = {x["kind"]: x for x in csv.DictReader(open(out / "kinds.csv"))}
    fwd = kinds["radio_hidden"]
    assert int(fwd["messages"]) == m["hidden_delivered"] + col["hidden_miss_radio"]
    assert int(fwd["miss_markers"]) == col["hidden_miss_sender"] + col["hidden_miss_radio"]
    assert int(kinds["bundle"]["miss_markers"]) == 0
    robots = list(csv.DictReader(open(out / "robots.csv")))
    assert [int(x["decisions"]) for x in robots] == [HORIZON] * ROBOTS
    assert all(float(x["latency_ms_p50"]) > 0 for x in robots)
    rows = list(csv.DictReader(open(out / "attention.csv")))
    # every 5th tick's attention of each robot, once (its final status repeated the last one)
    per_robot = len(range(0, HORIZON, 5))
    assert sorted(int(x["samples"]) for x in rows if x["distance"] == "0") == [per_robot] * ROBOTS
    made = json.loads((out / "trace.json").read_text())  # what the figures were made from
    assert made["attention_samples"] == per_robot * ROBOTS and made["source"] == {
        "recording": str(recorded["file"]), "run_id": "rec15", "policy": "commattn",
        "checkpoint": CKPT, "seed": 7, "episodes": 1, "partial": False, "damaged": None}
    assert made["command"].startswith("swarm trace ") and made["provenance"]["git"]
    # a trace of a recording without attention into the same folder leaves no stale figure
    synthetic(recorded["dir"] / "syn.mcap")
    assert swarm("trace", str(recorded["dir"] / "syn.mcap"), "--out", str(out)).returncode == 0
    assert not (out / "attention.png").exists() and (out / "links.png").exists()
    assert json.loads((out / "trace.json").read_text())["source"]["run_id"] == "syn"


# ------------------------------------------------------------------------ a killed recorder
def test_every_kind_has_a_json_form_that_fits_its_schema() -> None:
    from swarm.net.learning import RobotRollout, RolloutTick

    cfg = WorldConfig(n_robots=3)
    traj = Traj(0, 2, 1, 3, 4, bytes(50), [3, 4], bytes(25)).pack()
    hidden = Hidden(0, 2, 1, 5, bytes(16)).pack()
    samples = {
        "obs": Obs(0, 2, 1, 3, 4, bytes(25), -10.0, False, 12.5).pack(),
        "traj": traj, "bundle": Bundle(0, 2, 1, [traj]).pack(), "hidden": hidden,
        "radio_hidden": Hidden.miss(0, 2, 1).pack(), "action": Action(0, 2, 1, 7, 0.5).pack(),
        "rstatus": pack_record(K_RSTATUS, {"robot": 1, "ep": 0, "attn": [0.25, 0.75, 0.0],
                                           "attn_t": 2, "bytes": b"\x00"}),
        "rollout": RobotRollout(0, 1, [RolloutTick(traj, b"\xa0", True, 3, -0.5, 1.0, 2)]).pack(),
    }
    for kind, payload in samples.items():
        obj = msgjson.to_json(kind, payload, cfg)
        check_schema(obj, msgjson.SCHEMAS[kind], kind)
        json.dumps(obj, allow_nan=False)
    assert msgjson.to_json("bundle", samples["bundle"], cfg)["senders"] == [1]
    assert msgjson.to_json("radio_hidden", samples["radio_hidden"], cfg)["miss"] is True
    assert msgjson.to_json("rollout", samples["rollout"], cfg)["heard"] == [[0, 2]]
    assert set(msgjson.SCHEMAS) >= {Keys("r").kind_of(k)[0] for k in (
        Keys("r").status, Keys("r").result, Keys("r").end, Keys("r").control,
        Keys("r").weights, Keys("r").learner_status, Keys("r").episode,
        Keys("r").worker_episodes(3), Keys("r").rollout(0))}


def test_the_attention_field_is_range_checked() -> None:
    ok = {"robot": 1, "attn": [0.2, 0.8, 0.0], "attn_t": 3}
    assert check_robot_status(dict(ok), 3, 30) == ok
    assert check_robot_status({"robot": 2, "msgs_in": 4}, 3, 30)  # optional
    for bad in ({"attn": [0.2, 0.8]}, {"attn": [0.2, 0.9, 0.0]}, {"attn": [-0.1, 1.1, 0.0]},
                {"attn": [0.2, 0.8, float("nan")]}, {"attn_t": 31}, {"attn_t": None},
                {"attn": "x"}, {"robot": 3}):
        with pytest.raises(BadMessage):
            check_robot_status({**ok, **bad}, 3, 30)
    with pytest.raises(BadMessage):
        check_robot_status({"robot": 0, "attn_t": 1}, 3, 30)  # both or neither
    # its counters too: a bad one used to fail halfway through the dashboard's update
    for bad in ({"missed_hidden": "x"}, {"msgs_in": -1}, {"final": 1}, {"ep": -2},
                {"compute_ms": float("nan")}, {"errors": True}):
        with pytest.raises(BadMessage):
            check_robot_status({"robot": 0, **bad}, 3, 30)
    assert check_robot_status({"robot": 0, "ep": -1, "final": True, "errors": 2}, 3, 30)


def test_keys_know_which_run_and_kind_a_key_belongs_to() -> None:
    k = Keys("r1")
    assert k.kind_of(k.inbox(2)) == ("bundle", 2) and k.kind_of(k.status) == ("status", None)
    assert k.kind_of(k.inbox_hidden(0)) == ("radio_hidden", 0)
    assert k.kind_of(k.worker_episodes(12)) == ("worker_episodes", None)  # (no robot's key)
    assert Keys.worker_of(k.worker_episodes(12)) == 12 and Keys.worker_of(k.episode) is None
    for key in ("swarm/r2/world/status", "swarm/r1/worker/x/episodes", "swarm/r1/worker/1/eps",
                "swarm/r1/rollout/episode", "swarm/r1/robot/x/traj", "swarm/r1/robot/1/foo",
                "swarm/r1/world/obs/1/2", "swarm/r1/robot/9999999/traj", "swarm/r1"):
        assert k.kind_of(key) == ("", None), key


def test_the_map_draws_whom_each_robot_attends_to_most() -> None:
    v = SwarmView("att", "commattn", 6, 12, 3, 10.0, episodes=1)
    v.apply_status({"ep": 0, "t": 1, "pos": [[0, 0], [0, 6], [5, 11]],
                    "alive": [True, True, True], "elratio": 0.1, "timeouts": []}, now=0.0)
    for i in range(3):
        v.set_alive(i, True)
    v.apply_robot({"robot": 0, "attn": [0.5, 0.4, 0.1], "attn_t": 1})
    console = Console(file=io.StringIO(), width=160, record=True, color_system=None)
    console.print(render(v))
    text = console.export_text()
    assert "attention (strongest)" in text
    grid = [line for line in text.splitlines() if "∙∙" in line]
    assert grid and "0 ∙∙∙∙∙∙∙∙∙∙1" in grid[0].replace(" ", " ")  # robot 0 -> robot 1 (y 0)
    v.attention_focus = None
    console = Console(file=io.StringIO(), width=160, record=True, color_system=None)
    console.print(render(v))
    assert "∙∙" not in console.export_text() and "attention" not in console.export_text()


def test_the_tick_of_every_message_kind_is_read_in_one_place() -> None:
    """`messages.peek_tick` reads (episode, tick) from a payload's head as the schemas pack it (a
    direct-delivery `Stamped`: its inner message's, not (kind, episode)); whatever is not a
    message of one tick is None, so the recorder keeps its last tick for it (a robot's episode
    record used to be filed at tick <its robot id>). A bundle's senders in its JSON form are
    its trajectory messages' own, checked as a robot checks them."""
    import msgpack

    from swarm.net.learning import RobotRollout
    from swarm.net.messages import K_OBS, K_STATUS, K_TRAJ, SCHEMA, Stamped, peek_tick
    from swarm.procs.recorder import run_tick

    cfg = WorldConfig(n_robots=3)
    patch, visited = b"\0" * cfg.vision ** 2, b"\0" * ((cfg.cells + 7) // 8)
    obs = Obs(3, 17, 1, 2, 2, patch, 0.0, False, 5.0).pack()
    trajs = [Traj(3, 17, i, 2, i, visited, [], patch).pack() for i in (2, 0)]
    for payload, cls in ((obs, Obs), (trajs[0], Traj), (Action(3, 17, 1, 4, 1.0).pack(), Action),
                         (Bundle(3, 17, 1, trajs).pack(), Bundle),
                         (Hidden(3, 17, 1, 2, b"\0" * 8).pack(), Hidden)):
        m = cls.unpack(payload, cfg)
        assert peek_tick(payload) == (m.ep, m.t) == (3, 17)
    assert peek_tick(Stamped(K_TRAJ, 3, 17, 1, 0.0, trajs[0]).pack()) == (3, 17)
    assert peek_tick(obs, K_OBS) == (3, 17) and peek_tick(trajs[0], K_OBS) is None
    bad = [b"not msgpack", b"", msgpack.packb([SCHEMA, K_OBS, -1, 2]),
           msgpack.packb([SCHEMA, K_OBS, 1.0, 2]), msgpack.packb([SCHEMA, K_OBS, True, 2]),
           msgpack.packb([SCHEMA + 1, K_OBS, 1, 2]), msgpack.packb([SCHEMA, K_OBS, 1]),
           msgpack.packb({"ep": 1}), pack_record(K_STATUS, {"ep": 3, "t": 17}),
           RobotRollout(3, 2, []).pack()]
    assert [peek_tick(p) for p in bad] == [None] * len(bad)
    rec = RunRecord(cfg, RunConfig(run_id="r1", episodes=5))
    assert run_tick(peek_tick(RobotRollout(3, 2, []).pack()), rec, 40) == 40  # (the last one)
    assert run_tick(None, rec, None) is None  # (none yet: the recorder holds it for the next)
    bundle = Bundle(3, 17, 1, trajs).pack()
    assert msgjson.to_json("bundle", bundle, cfg)["senders"] == [2, 0]
    stray = Traj(3, 16, 1, 2, 2, visited, [], patch).pack()  # another tick's message
    with pytest.raises(BadMessage):
        msgjson.to_json("bundle", Bundle(3, 17, 1, [trajs[0], stray]).pack(), cfg)


def _inject(src: Path, dst: Path, extra: dict[int, list[tuple[str, str, bytes, int | None]]]
            ) -> None:
    """`src` rewritten by the recorder's writer with messages (key, kind, payload, tick: None,
    that of the message there) filed before the message at each index (-1: after the last)."""
    from swarm.net.record.recording import RUN_RECORD
    from swarm.studies.replay import load

    r = load(str(src))
    w = RecordingWriter(dst, r.record.run.run_id, r.raw.attachment(RUN_RECORD), r.record.world,
                        r.record.run.clock, r.record.run.tick_timeout)
    msgs = list(r.messages)
    for i, m in [*enumerate(msgs), (-1, msgs[-1])]:
        mine = [(m.key, m.kind, m.payload, m.tick)] if i >= 0 else []
        for key, kind, payload, tick in [*extra.get(i, []), *mine]:
            form = w.decode(key, kind, payload)
            w.message(key, kind, payload, None if form is None else form[1], m.wall_ns,
                      m.tick if tick is None else tick, m.vtime_ns)
    w.finish(r.result, {"ended": "end"})


def test_strays_the_world_dropped_are_no_divergence_and_crash_no_reader(
        recorded: dict[str, Any], tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Review helper 92: a readable action for the next tick filed before that tick's
    observation, and a status of a later tick filed early (both dropped by the world and the
    supervisor), made `--verify` report a divergence and `replay --until` stop there; a status
    whose link or fault entries had another shape crashed `replay` and `trace` (and the live
    dashboard, which reads them the same way); the supervisor's check now drops it."""
    from conftest import swarm_here

    from swarm.studies.replay import load

    cfg = WorldConfig(n_robots=ROBOTS, horizon=HORIZON)
    r = load(str(recorded["file"]))
    msgs = r.messages
    at = next(k for k, m in enumerate(msgs) if m.kind == "action" and m.robot == 0 and
              Action.unpack(m.payload, cfg).t == 3)  # robot 0's action of tick 3, then a stray
    real = next(Action.unpack(m.payload, cfg) for m in msgs if m.kind == "action"  # of tick 4
                and m.robot == 0 and Action.unpack(m.payload, cfg).t == 4)
    stray = Action(real.ep, real.t, 0, real.action % 8 + 1, real.planning_ms).pack()
    st = unpack_record(r.of("status")[1].payload, K_STATUS)
    ahead = pack_record(K_STATUS, {**st, "t": 7, "run_tick": 7})
    key = Keys(r.record.run.run_id)
    odd = [pack_record(K_STATUS, {**unpack_record(r.of("status")[-1].payload, K_STATUS),
                                  **change}) for change in ({"links": {"0-1": [1]}},
                                                            {"faults": [1]})]
    strays = tmp_path / "strays.mcap"
    _inject(recorded["file"], strays, {at + 1: [(msgs[at].key, "action", stray, None)],
                                       10: [(key.status, "status", ahead, 7),  # and one
                                            (key.status, "status",  # of no episode
                                             pack_record(K_STATUS, {"run_tick": 0}), 0)],
                                       -1: [(key.status, "status", p, None) for p in odd]})
    out = tmp_path / "v.json"
    got = swarm_here("replay", str(strays), "--verify", "--json", str(out), capsys=capsys)
    assert got.returncode == 0, got.stderr
    assert json.loads(out.read_text())["checked"]["statuses"] == HORIZON
    got = swarm_here("replay", str(strays), "--speed", "0", "--until", "6", capsys=capsys)
    assert got.returncode == 0 and "(ticks 0..6" in got.stdout + got.stderr, got.stderr
    # the dashboard shows the statuses the supervisor took, not the one of tick 7 filed early
    from swarm.studies.replay import replay

    _, stats = replay(load(str(strays)), speed=0, live=False)
    assert (stats.statuses, stats.bad) == (HORIZON, 4), stats  # (ahead, no episode, odd x2)
    got = swarm_here("trace", str(strays), "--out", str(tmp_path / "t"), capsys=capsys)
    assert got.returncode == 0, got.stderr


def test_a_recorder_stopped_before_any_tick_writes_what_it_held(
        recorded: dict[str, Any], tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """Messages that name no tick are held until one does; a recorder that ended first (a run
    stopped while starting) left them unwritten and in no counter (review helper 92). And
    `swarm trace --partial` says the file is cut, as `swarm replay` does."""
    from conftest import swarm_here

    from swarm.net.record.recording import RUN_RECORD, read
    from swarm.procs.recorder import Recorder
    from swarm.studies.replay import load

    r = load(str(recorded["file"]))
    rec, held = r.record, tmp_path / "held.mcap"
    recorder = Recorder(rec.run.run_id, str(held), None)  # (no session: fed by hand)
    w = RecordingWriter(held, rec.run.run_id, r.raw.attachment(RUN_RECORD), rec.world,
                        rec.run.clock, rec.run.tick_timeout)
    for m in r.of("rstatus")[:3]:  # robots' statuses before the world's first
        recorder.q.put_nowait((m.wall_ns, m.key, m.payload))
    recorder._drain(w, rec)  # (what the recorder does on its way out)
    w.finish(None, {"ended": "interrupted", "received": recorder.c.received})
    assert len(read(held).messages) == recorder.c.received == 3 and not recorder.held
    # a status far ahead (a stray) does not move the clock the robots' statuses are filed by
    st = [unpack_record(m.payload, K_STATUS) for m in r.of("status")[:2]]
    stray = pack_record(K_STATUS, {**st[0], "t": 6, "run_tick": 6})
    w = RecordingWriter(tmp_path / "clock.mcap", rec.run.run_id, r.raw.attachment(RUN_RECORD),
                        rec.world, rec.run.clock, rec.run.tick_timeout)
    m = r.of("rstatus")[0]
    for key, payload in ((r.of("status")[0].key, pack_record(K_STATUS, st[0])),
                         (r.of("status")[0].key, stray), (m.key, m.payload)):
        recorder._write(w, rec, 0, key, payload)
    assert recorder.tick == st[0]["run_tick"]  # (the stray was filed, at its own tick)
    recorder._write(w, rec, 0, r.of("status")[1].key, pack_record(K_STATUS, st[1]))
    assert recorder.tick == st[1]["run_tick"]
    w.finish(None, {"ended": "end"})
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(recorded["file"].read_bytes()[:-20])
    got = swarm_here("trace", str(cut), "--partial", "--out", str(tmp_path / "t"), capsys=capsys)
    assert got.returncode == 0 and "partial recording" in got.stderr, got.stderr
