"""`swarm record` and `swarm replay` from the command line: a SIGKILLed recorder, a recorder
started by hand late (a local run found by its id), runs it cannot join, bad files and
out-of-range ticks."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest
from conftest import ROOT, swarm, swarm_started

pytest.importorskip("mcap")  # the `record` extra (in `test` too)

from test_record import rewrite, swarm_main, synthetic  # noqa: E402


@pytest.mark.procs
def test_a_sigkilled_recorder_leaves_a_readable_file(tmp_path: Path) -> None:
    f = tmp_path / "cut.mcap"
    proc = subprocess.Popen(
        [sys.executable, "-m", "swarm.cli", "run", "--headless", "--robots", "2", "--episodes",
         "3", "--pace", "12", "--run-id", "rec15kill", "--record", str(f), "--log-dir",
         str(tmp_path / "logs")], cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
        text=True)
    try:
        assert proc.stdout is not None
        # the first tick's status: the robots run, the recorder writes. The run lasts ~7.5 s
        # (90 ticks at 12/s), long enough under load for a chunk to be flushed and the
        # recorder killed before the run would have ended it (at 25 ticks/s and 2 episodes the
        # run could end first on a loaded machine).
        proc.stdout.readline()
        deadline = time.monotonic() + 30
        for _ in range(2):  # until two chunks are flushed (0.5 s apart): the first may hold
            size = f.stat().st_size  # tick 0 alone, and a cut there leaves no tick to verify
            while f.stat().st_size <= size and time.monotonic() < deadline:
                time.sleep(0.05)
        pids = [int(p) for p in os.listdir("/proc") if p.isdigit() and
                b"record\0--run-id\0rec15kill" in _cmdline(int(p))]
        assert pids, "no recorder process"
        os.kill(pids[0], signal.SIGKILL)
        rest, err = proc.communicate(timeout=90)
        # the run went on without its recorder and completed, but the recording asked for is
        # partial: data lost, said in one warning line, and exit status 1
        assert proc.returncode == 1, err[-1500:]
    finally:
        if proc.poll() is None:
            proc.kill()
    res = json.loads(rest.strip().splitlines()[-1])["result"]
    assert res["completed"] == 3
    assert res["recording"]["exit"] == -signal.SIGKILL and res["recording"]["partial"] is True
    said = [x for x in err.splitlines() if "recorder" in x]
    assert len(said) == 1 and said[0].startswith("swarm: warning: the recorder failed (killed "
                                                 "by SIGKILL)") and str(f) in said[0], err
    # the mcap package's own stream reader reads every record up to the cut
    from mcap.stream_reader import StreamReader

    seen = 0
    with pytest.raises(Exception), open(f, "rb") as fh:  # noqa: B017 (it ends mid-file)
        for rec in StreamReader(fh).records:
            seen += type(rec).__name__ == "Message"
    assert seen > 0
    r = swarm("replay", str(f), "--verify")
    assert r.returncode == 2 and "truncated" in r.stderr and "--partial" in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1
    r = swarm("replay", str(f), "--verify", "--partial")
    assert r.returncode == 0, r.stderr
    r = swarm("trace", str(f), "--partial", "--out", str(tmp_path / "trace"))
    assert r.returncode == 0, r.stderr


def _cmdline(pid: int) -> bytes:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes()
    except OSError:
        return b""


# ------------------------------------------------------------ a recorder started by hand
@pytest.fixture(scope="module")
def hand_recorded(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    """One run (2 robots, 3 episodes of 20 ticks at 8 ticks/s: ~7.5 s) and two recorders
    started by hand as the README shows them (`swarm record --run-id R --out F`, no --connect):
    `early` started 2 s before the run (whether it was still waiting then is noted), `late`
    after the run's first tick. (One run for the two tests below; each started its own.)"""
    tmp = tmp_path_factory.mktemp("hand")
    early, late = tmp / "early.mcap", tmp / "late.mcap"
    got: dict[str, Any] = {"early": early, "late": late}
    rec = subprocess.Popen([sys.executable, "-m", "swarm.cli", "record", "--run-id", "rec15late",
                            "--out", str(early), "--wait", "60"], cwd=ROOT,
                           stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        time.sleep(2.0)  # the recorder is looking for the run
        got["waiting"] = rec.poll() is None
        run = swarm_started("run", "--headless", "--robots", "2", "--episodes", "3", "--horizon",
                            "20", "--pace", "8", "--run-id", "rec15late", "--log-dir",
                            str(tmp / "logs"))
        try:
            got["late_rec"] = swarm("record", "--run-id", "rec15late", "--out", str(late),
                                    "--wait", "10", timeout=60)
            _, err = run.communicate(timeout=60)  # (its status lines drained, or it blocks)
            got["run"] = (run.returncode, err)
        finally:
            if run.poll() is None:
                run.kill()
        got["early_rec"] = (rec.communicate(timeout=60), rec.returncode)
    finally:
        if rec.poll() is None:
            rec.kill()
    return got


@pytest.mark.procs
def test_swarm_record_joins_a_local_run_by_its_id_late(hand_recorded: dict[str, Any],
                                                       tmp_path: Path) -> None:
    """`swarm record --run-id R --out F` as the README shows it (no --connect) finds the run
    this machine started, here after its first tick: replay names the ticks the file holds,
    --verify refuses it in one line (it re-steps a run from its start), --from past its end too.
    (The `late` recorder of `hand_recorded`.)"""
    f = hand_recorded["late"]
    r = hand_recorded["late_rec"]
    assert r.returncode == 0, r.stderr[-1500:]
    code, err = hand_recorded["run"]
    assert code == 0, err[-1500:]
    r = swarm("replay", str(f), "--speed", "0")
    first, last = (int(x) for x in r.stdout.split("(ticks ")[1].split(";")[0].split(".."))
    assert r.returncode == 0 and 0 < first < last == 60, r.stdout[-300:]
    assert f"recording starts mid-run: at run tick {first}" in r.stderr
    # every message lies within the span: what came before the first tick named (the robots'
    # statuses) was filed at run tick 0, and `--from` its first tick lost it (UA pass)
    from swarm.net.record.recording import read

    assert min(m.tick for m in read(f).messages) == first
    counts = []
    for flags in ([], ["--from", str(first)]):
        js = tmp_path / "replayed.json"
        r = swarm("replay", str(f), "--speed", "0", "--json", str(js), *flags)
        assert r.returncode == 0, r.stderr
        counts.append(json.loads(js.read_text())["messages"])
    assert counts[0] == counts[1] == len(read(f).messages), counts
    r = swarm("replay", str(f), "--verify")
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert f"starts mid-run, at run tick {first} (episode {first // 20}" in r.stderr
    r = swarm("replay", str(f), "--from", "500")
    assert r.returncode == 2 and r.stderr.strip() == (
        f"swarm: error: --from 500 is past the end of {f} (run ticks {first}..60)")


@pytest.mark.procs
def test_swarm_record_started_before_its_run_waits_for_it(hand_recorded: dict[str, Any]
                                                          ) -> None:
    """UA pass: `swarm record --run-id R` started before the run exited at once ("no running
    swarm"), though its --wait waits for the world; it now waits for the run to start. (The
    `early` recorder of `hand_recorded`.)"""
    f = hand_recorded["early"]
    (out, err), code = hand_recorded["early_rec"]
    assert hand_recorded["waiting"], (out, err)
    code_run, err_run = hand_recorded["run"]
    assert code_run == 0, err_run[-1500:]
    assert code == 0, err[-1500:]
    r = swarm("replay", str(f), "--speed", "0")
    assert r.returncode == 0 and "(ticks " in r.stdout, r.stdout[-300:] + r.stderr[-300:]


@pytest.mark.procs
def test_swarm_record_stopped_by_ctrl_c_finishes_its_file_and_exits_130(tmp_path: Path) -> None:
    """A recorder started by hand ends with its run; stopped first (Ctrl-C) it said nothing of
    it and exited 0, where every other command stopped so exits 130. It still writes its
    footer and its summary line (`ended: interrupted`), then `swarm: interrupted`."""
    f = tmp_path / "stopped.mcap"
    run = swarm_started("run", "--headless", "--robots", "2", "--episodes", "50", "--pace",
                        "12", "--run-id", "rec81int", "--log-dir", str(tmp_path / "logs"))
    try:
        rec = subprocess.Popen([sys.executable, "-m", "swarm.cli", "record", "--run-id",
                                "rec81int", "--out", str(f), "--wait", "30"], cwd=ROOT,
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        try:
            opened = 0
            for _ in range(2):  # the file opened, then a chunk flushed: the recorder writes
                while (f.stat().st_size if f.exists() else 0) <= opened:
                    assert rec.poll() is None, rec.communicate()
                    time.sleep(0.05)
                opened = f.stat().st_size
            rec.send_signal(signal.SIGINT)
            _, err = rec.communicate(timeout=60)
        finally:
            if rec.poll() is None:
                rec.kill()
    finally:
        run.send_signal(signal.SIGINT)
        run.communicate(timeout=60)
    *summary, last = err.strip().splitlines()
    assert rec.returncode == 130 and last == "swarm: interrupted", err[-1500:]
    assert len(summary) == 1 and json.loads(summary[0])["ended"] == "interrupted", err[-1500:]
    r = swarm("replay", str(f), "--speed", "0")  # whole: no --partial needed
    assert r.returncode == 0 and "recording starts mid-run" in r.stderr, r.stderr[-1500:]


@pytest.mark.procs
def test_an_interrupted_recorded_run_leaves_no_logs_and_a_readable_file(tmp_path: Path) -> None:
    """Ctrl-C on `swarm run --record` kept the run's log folder every time (named on stderr):
    its recorder's summary line, in its log, read as more than an interruption."""
    tmp, f = tmp_path / "tmp", tmp_path / "int.mcap"
    tmp.mkdir()
    proc = subprocess.Popen([sys.executable, "-m", "swarm.cli", "run", "--headless", "--robots",
                             "2", "--episodes", "20", "--pace", "12", "--run-id", "rec81run",
                             "--record", str(f)], cwd=ROOT, env={**os.environ, "TMPDIR": str(tmp)},
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    assert proc.stdout is not None
    proc.stdout.readline()  # the first tick's status: the recorder is up (robots wait for it)
    _stopped_leaving_nothing(proc, tmp, signal.SIGINT)
    r = swarm("replay", str(f), "--verify", "--partial")
    assert r.returncode == 0, r.stderr[-1500:]


def test_swarm_record_refuses_a_run_it_cannot_join(tmp_path: Path, capsys: Any) -> None:
    """No local run of that id after --wait, or a secure one without --secure (at once): one
    line, exit 2."""
    from swarm.common.atomic import write_json
    from swarm.common.spawn import registry

    out = str(tmp_path / "x.mcap")
    code, err = swarm_main("record", "--run-id", "rec15none", "--out", out, "--wait", "0.5",
                           capsys=capsys)
    assert code == 2 and "no running swarm 'rec15none' on this machine" in err, err
    assert "(waited 0.5 s)" in err, err
    entry = write_json(registry("rec15tls"), {"hub": "tls/127.0.0.1:9", "pid": os.getpid()})
    try:
        code, err = swarm_main("record", "--run-id", "rec15tls", "--out", out, "--wait", "3",
                               capsys=capsys)
    finally:
        entry.unlink()
    assert code == 2 and err == ("swarm: error: run rec15tls is secure: give --secure DIR (the "
                                 "recorder's certificate)")
    assert not Path(out).exists()
    code, err = swarm_main("record", "--run-id", "r", "--out", out, "--wait", "nan",
                           capsys=capsys)
    assert code == 2 and "--wait must lie in [0.1, 3600] seconds, got nan" in err, err
    # UA pass: a world that never answers is named with --wait as given, not "1.99932 s"
    code, err = swarm_main("record", "--run-id", "rec15nosuch", "--out", out, "--connect",
                           "tcp/127.0.0.1:1", "--wait", "0.5", capsys=capsys)
    assert code == 2 and err == ("swarm: error: no world answered on swarm/rec15nosuch/world/"
                                 "config within 0.5 s"), err


def test_a_query_timeout_names_its_budget_as_a_person_would() -> None:
    """A caller's remaining budget (a measured 0.29996 s) is said as 0.3 s."""
    from swarm.net.inbox import query
    from swarm.net.zconfig import ZenohOptions, open_session

    with open_session(ZenohOptions()) as session, pytest.raises(TimeoutError) as exc:
        query(session, "swarm/rec15q/world/config", 0.29996, bytes)
    assert str(exc.value) == "no answer on swarm/rec15q/world/config within 0.3 s"


# ---------------------------------------------------------------------------- bad files
@pytest.mark.procs  # one CLI subprocess at the end
def test_bad_files_are_one_line_errors_with_status_2(tmp_path: Path, capsys: Any) -> None:
    good = tmp_path / "good.mcap"
    synthetic(good)
    assert swarm_main("replay", str(good), "--speed", "0", capsys=capsys)[0] == 0
    capsys.readouterr()
    (tmp_path / "text.mcap").write_text("hello, not a recording\n" * 10)
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(good.read_bytes()[: good.stat().st_size // 2])
    other_schema = tmp_path / "schema.mcap"
    rewrite(good, other_schema, edit_meta=lambda n, d: {**d, "schema": "99"}
            if n == "swarm.recording" else d)
    foreign = tmp_path / "foreign.mcap"
    rewrite(good, foreign, rename=lambda t: t.replace("swarm/syn/world/obs/1",
                                                      "swarm/other/world/obs/1"))
    outside = tmp_path / "outside.mcap"
    rewrite(good, outside, rename=lambda t: t.replace("obs/1", "obs/7"))
    cases = {"text.mcap": "not an MCAP file", "cut.mcap": "truncated",
             "schema.mcap": "schema version '99'", "foreign.mcap": "not a key of run syn",
             "outside.mcap": "not a key of run syn", "missing.mcap": "cannot read"}
    for name, why in cases.items():
        for command in (["replay", "--verify"], ["replay"], ["trace", "--out", str(tmp_path)]):
            code, err = swarm_main(command[0], str(tmp_path / name), *command[1:],
                                   capsys=capsys)
            assert code == 2, (name, command, err)
            assert len(err.splitlines()) == 1 and why in err, (name, err)
    for flags, why in ((["--from", "3"], "--from 3 is past the end of"),  # ticks 0..2
                       (["--from", "2", "--until", "1"], "--until 1 is before --from 2")):
        code, err = swarm_main("replay", str(good), "--speed", "0", *flags, capsys=capsys)
        assert code == 2 and len(err.splitlines()) == 1 and why in err, (flags, err)
    # an empty --out (Path("") is the working directory) before the file is even read
    code, err = swarm_main("trace", str(tmp_path / "missing.mcap"), "--out", "", capsys=capsys)
    assert code == 2 and err == "swarm: error: --out wants a directory, got an empty name", err
    r = swarm("replay", str(tmp_path / "cut.mcap"))  # and no traceback from the real CLI
    assert r.returncode == 2 and "Traceback" not in r.stderr


def test_replay_counts_only_the_ticks_it_replays(tmp_path: Path, capsys: Any) -> None:
    """UA pass: `--from` fast-forwards through the ticks before it, and the summary counted
    them (and their bad records) as replayed; a file with no tick in it said "replayed 0
    messages (ticks 0..0)"."""
    good = tmp_path / "good.mcap"
    synthetic(good, bad_status_at=(0, 2))  # 2 robots' observations at ticks 0..2
    js = tmp_path / "replayed.json"  # what the summary line says
    for flags, said in (([], (8, 0, 2, 2)), (["--from", "2"], (3, 2, 2, 1)),
                        (["--from", "1", "--until", "1"], (2, 1, 1, 0))):
        code, _ = swarm_main("replay", str(good), "--speed", "0", "--json", str(js), *flags,
                             capsys=capsys)
        got = json.loads(js.read_text())
        assert code == 0 and (got["messages"], got["first_tick"], got["last_tick"],
                              got["bad"]) == said, (flags, got)
    from swarm.net.record.recording import RecordingWriter
    from swarm.procs.runconfig import RunConfig, RunRecord
    from world.config import WorldConfig

    cfg, empty = WorldConfig(n_robots=2, horizon=4), tmp_path / "empty.mcap"
    w = RecordingWriter(tmp_path / "started.mcap", "syn",  # a recorder killed at its start:
                        RunRecord(cfg, RunConfig(run_id="syn")).to_record(), cfg, "virtual", 2.0)
    w.fh.flush()
    empty.write_bytes((tmp_path / "started.mcap").read_bytes())  # its run record, no message
    w.finish(None, {})
    code, err = swarm_main("replay", str(empty), "--partial", capsys=capsys)
    assert code == 1 and err == (f"swarm: replay: {empty}: nothing to replay (no tick in it; "
                                 "it is cut before its first)"), err


def test_a_file_damaged_in_the_middle_is_not_called_cut_by_the_recorder(
        tmp_path: Path, capsys: Any) -> None:
    """UA pass: 200 bytes flipped mid-file were reported as "the recorder stopped at run tick
    N": the recorder finished that file (it ends in the closing magic); say where it is
    damaged instead."""
    good, mid = tmp_path / "good.mcap", tmp_path / "mid.mcap"
    synthetic(good)
    data = bytearray(good.read_bytes())
    at = data.index(b"swarm/syn/world/obs/1") + 40  # inside the messages' chunk
    data[at:at + 200] = bytes(b ^ 0xFF for b in data[at:at + 200])
    mid.write_bytes(bytes(data))
    code, err = swarm_main("replay", str(mid), "--speed", "0", capsys=capsys)
    assert code == 2 and "is damaged or cut: unreadable at bytes " in err, err
    code, err = swarm_main("replay", str(mid), "--speed", "0", "--partial", capsys=capsys)
    assert "damaged recording: unreadable at bytes " in err and "recorder stopped" not in err, err
    cut = tmp_path / "cut.mcap"  # a file cut short is still the recorder stopping
    cut.write_bytes(good.read_bytes()[:-100])
    code, err = swarm_main("replay", str(cut), "--speed", "0", "--partial", capsys=capsys)
    assert code == 0 and "partial recording: the recorder stopped at run tick" in err, err


# ----------------------------------------------------------------------- units, no processes


@pytest.mark.procs
def test_a_recorder_waiting_for_its_world_stops_on_ctrl_c(tmp_path: Path) -> None:
    """Ctrl-C while `swarm record` still waits for the run's world (its `--wait`) ends it at once
    with 130 and no file; it used to wait the whole --wait out."""
    out = tmp_path / "w.mcap"
    proc = subprocess.Popen([sys.executable, "-m", "swarm.cli", "record", "--run-id", "nowhere",
                             "--connect", "tcp/127.0.0.1:9", "--out", str(out), "--wait", "60"],
                            cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        time.sleep(2.0)  # loaded, session open, asking for the world
        proc.send_signal(signal.SIGINT)
        assert proc.wait(timeout=10) == 130, proc.communicate()
    finally:
        if proc.poll() is None:
            proc.kill()
    assert not out.exists()


@pytest.mark.procs
def test_bench_record_without_out_removes_its_recordings_also_when_interrupted(
        tmp_path: Path) -> None:
    """`swarm bench record` without --out keeps no recordings: its temporary folder is gone
    after a finished run and after Ctrl-C (it stayed in the temp dir)."""
    tmp = tmp_path / "tmp"
    tmp.mkdir()
    env = {**os.environ, "TMPDIR": str(tmp)}
    r = swarm("bench", "record", "--pairs", "1", "--episodes", "1", "--robots", "2", "--json",
              str(tmp_path / "b.json"), env={"TMPDIR": str(tmp)})
    assert r.returncode == 0, r.stderr
    assert json.loads((tmp_path / "b.json").read_text())["median_bytes"] > 0
    assert not list(tmp.glob("swarm-bench-record-*"))
    proc = subprocess.Popen([sys.executable, "-m", "swarm.cli", "bench", "record", "--pairs",
                             "200", "--episodes", "5", "--robots", "2"], cwd=ROOT, env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 60
        while not list(tmp.glob("swarm-bench-record-*/run0.mcap")):
            assert time.monotonic() < deadline and proc.poll() is None, proc.communicate()
            time.sleep(0.2)
        proc.send_signal(signal.SIGINT)
        proc.wait(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert not list(tmp.glob("swarm-bench-record-*"))


@pytest.mark.procs
@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_bench_record_interrupted_while_its_robots_start_leaves_nothing(
        tmp_path: Path, sig: signal.Signals) -> None:
    """Interrupted as its robots started, `bench record` left its run's log folder in the temp
    dir (named on stderr): each robot stopped while it still loaded its modules wrote the
    KeyboardInterrupt's traceback, which was read as more than an interruption."""
    tmp = tmp_path / "tmp"
    tmp.mkdir()
    proc = subprocess.Popen([sys.executable, "-m", "swarm.cli", "bench", "record", "--pairs",
                             "200", "--episodes", "5", "--robots", "4"], cwd=ROOT,
                            env={**os.environ, "TMPDIR": str(tmp)}, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    while not list(tmp.glob("swarm-brec-*/robot*.log")):  # (the robots are loading)
        assert proc.poll() is None, proc.communicate()
        time.sleep(0.01)
    _stopped_leaving_nothing(proc, tmp, sig)
    assert not list((tmp / "swarm-runs").iterdir())


def _stopped_leaving_nothing(proc: subprocess.Popen[str], tmp: Path, sig: int) -> None:
    """Send `sig` to the command `proc` (its TMPDIR `tmp`): it exits 130, names no log folder
    and leaves none (only the run-id registry folder stays)."""
    try:
        proc.send_signal(sig)
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    kept = {str(p): p.read_text(errors="replace")[-1500:] for p in tmp.rglob("*.log")}
    assert proc.returncode == 130 and "logs are in" not in err, (err, kept)
    assert [p.name for p in tmp.iterdir()] == ["swarm-runs"], list(tmp.rglob("*"))


def test_an_interrupts_traceback_says_no_more_than_interrupted() -> None:
    """What a child stopped while it loaded its modules writes (even inside `site`, before any
    line of ours) is an interruption; any other exception, or other words, are more."""
    from swarm.common.spawn import says_more_than_interrupted as more

    tb = ["Traceback (most recent call last):", '  File "x.py", line 1, in <module>', "    a",
          "    ^^^", ""]
    site = ["Fatal Python error: init_import_site: Failed to import the site module",
            "Python runtime state: initialized"]
    assert not more(["swarm: interrupted", ""])
    assert not more([*tb, "KeyboardInterrupt"]) and not more([*site, *tb, "KeyboardInterrupt"])
    assert not more(["Fatal Python error: init_sys_streams: can't initialize sys standard "
                     "streams", "Python runtime state: core initialized", *tb,
                     "KeyboardInterrupt"])
    assert not more([*tb, "KeyboardInterrupt", "swarm: interrupted"])
    assert more([*tb, "ValueError: bad"]) and more([*site, *tb, "ImportError: no"])
    assert not more(["Could not import runpy module", *tb, "KeyboardInterrupt"])
    chained = "During handling of the above exception, another exception occurred:"
    assert not more([*site, *tb, "KeyError: '/lib-dynload'", "", chained, "", *tb,
                     "KeyboardInterrupt"])  # (an exception that importing handles, then ^C)
    assert more([*tb, "KeyboardInterrupt", "", chained, "", *tb, "OSError: x"])
    assert more(["WARNING zenoh: something"]) and more(tb)  # (a traceback cut short)
    # two more forms a robot ^C'd at 1.0-1.2 s wrote (UA pass 41: its folder was kept): an
    # exception Python could only print, and its dump once stderr itself was gone
    ignored = "Exception ignored in: <module 'threading' from '/usr/lib/threading.py'>"
    assert not more([ignored, *tb, "KeyboardInterrupt: "])
    dump = ["object refcount : 2", "object type     : 0x7fb9c24521e0",
            "object type name: KeyboardInterrupt", "object repr     : KeyboardInterrupt()",
            "lost sys.stderr"]
    assert not more([*tb[:-2], "    ^^^^^^^object address  : 0x7fb9c1ae3fa0", *dump])
    assert more([*tb[:-2], "    ^^^object address  : 0x1", dump[0], dump[1],
                 "object type name: MemoryError", "lost sys.stderr"])
    assert more([ignored, *tb, "ValueError: x"])


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_a_child_stopped_before_its_cli_loaded_says_only_interrupted(sig: signal.Signals) -> None:
    """A supervisor's child stopped at once, while its interpreter still starts, holds the
    signal (`start_child` blocks it) until its CLI can take it: one line and status 130, no
    traceback of `site` or a `.pth` file (a CI run kept a run's logs for one)."""
    from swarm.common.spawn import PARENT_ENV, cli_args, start_child

    for _ in range(3):
        proc = start_child(cli_args("--version"), cwd=ROOT, stdout=subprocess.PIPE,
                           stderr=subprocess.PIPE, text=True,
                           env={**os.environ, PARENT_ENV: str(os.getpid())})
        proc.send_signal(sig)
        out, err = proc.communicate(timeout=60)
        assert (proc.returncode, out, err) == (130, "", "swarm: interrupted\n")


def test_replay_and_trace_refuse_to_write_over_their_recording(tmp_path: Path,
                                                               capsys: Any) -> None:
    """UA pass: `swarm replay run.mcap --verify --json run.mcap` said "verified ... every one as
    recorded", exit 0, and left 331 bytes of JSON where the recording was."""
    good = tmp_path / "good.mcap"
    synthetic(good)
    before = good.read_bytes()
    for argv, why in (
            (["replay", str(good), "--verify", "--json", str(good)],
             f"--json {good} is also the input file, which this command reads"),
            (["replay", str(good), "--speed", "0", "--json", f"{tmp_path}/./good.mcap"],
             "is also the input file, which this command reads"),
            (["trace", str(good), "--out", str(tmp_path / "t"), "--json", str(good)],
             "is also the input file"),
            (["trace", str(good), "--out", str(tmp_path / "t"), "--json", str(tmp_path / "t")],
             "--json and --out are the same file"),
            (["trace", str(good), "--out", str(tmp_path / "t"), "--json",
              str(tmp_path / "t" / "kinds.csv")], "--json and --out's kinds.csv are the same")):
        code, err = swarm_main(*argv, capsys=capsys)
        assert code == 2 and len(err.splitlines()) == 1 and why in err, (argv, err)
    assert good.read_bytes() == before and not (tmp_path / "t").exists()
    # a recording named like a file trace writes, in its --out folder
    named = tmp_path / "links.csv"
    named.write_bytes(before)
    code, err = swarm_main("trace", str(named), "--out", str(tmp_path), capsys=capsys)
    assert code == 2 and "--out's links.csv" in err and named.read_bytes() == before, err


def test_json_forms_may_be_missing_only_where_the_recorder_never_wrote_them(
        tmp_path: Path) -> None:
    """JSON forms are written after the run: a finished file holds one per raw payload (but
    the ones its interrupted recorder skipped, `json_skipped`), a cut one may lack any."""
    from swarm.net.keys import Keys
    from swarm.net.messages import Obs
    from swarm.net.record.recording import RecordingWriter, check_json_forms, read
    from swarm.procs.runconfig import RunConfig, RunRecord
    from world.config import WorldConfig

    good = tmp_path / "good.mcap"
    synthetic(good)  # 2 robots' observations at ticks 0..2, each with its JSON form
    cfg = WorldConfig(n_robots=2, horizon=4)
    assert check_json_forms(read(good), cfg) == (6, None)

    def raw_only(path: Path, skipped: int | None, finish: bool = True) -> None:
        w = RecordingWriter(path, "syn", RunRecord(cfg, RunConfig(run_id="syn")).to_record(),
                            cfg, "virtual", 2.0)
        for t in range(2):
            p = Obs(0, t, 1, 1, 1, bytes(cfg.vision ** 2), 0.0, False, 100.0).pack()
            w.message(Keys("syn").obs(1), "obs", p, None, 10**18 + t, t, 0)
        w.w.flush()
        if finish:
            w.finish(None, {} if skipped is None else {"json_skipped": skipped})

    for skipped, said in ((None, (0, 0)), (1, (0, 0)), (2, None)):
        raw_only(tmp_path / "raw.mcap", skipped)
        n, bad = check_json_forms(read(tmp_path / "raw.mcap"), cfg)
        assert n == 0 and (bad is None if said is None else bad[0].startswith(
            "swarm/syn/world/obs/1/json (no JSON form") and bad[2] == said), (skipped, bad)
    raw_only(tmp_path / "cut.mcap", None, finish=False)
    assert check_json_forms(read(tmp_path / "cut.mcap", partial=True), cfg) == (0, None)


def test_trace_of_a_recording_with_no_tick_writes_nothing_and_warns_of_nothing(
        tmp_path: Path, capsys: Any) -> None:
    """UA pass: `swarm trace` on a run stopped during its start-up exited 0 with header-only
    CSVs and empty figures, and leaked matplotlib's "No artists with labels found to put in
    legend"; `swarm replay` said `nothing to replay`, exit 1. Trace now says the same."""
    import warnings

    from swarm.net.record.recording import RecordingWriter
    from swarm.procs.runconfig import RunConfig, RunRecord
    from world.config import WorldConfig

    cfg, started = WorldConfig(n_robots=2, horizon=4), tmp_path / "started.mcap"
    RecordingWriter(started, "syn", RunRecord(cfg, RunConfig(run_id="syn")).to_record(), cfg,
                    "virtual", 2.0).finish(None, {})
    code, err = swarm_main("trace", str(started), "--out", str(tmp_path / "t"), "--json",
                           str(tmp_path / "t.json"), capsys=capsys)
    assert code == 1 and err == f"swarm: trace: {started}: nothing to trace (no tick in it)", err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["started.mcap"]
    good = tmp_path / "good.mcap"
    synthetic(good)  # ticks, but no status: no elratio line to label
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        code, err = swarm_main("trace", str(good), "--out", str(tmp_path / "t"), capsys=capsys)
    assert code == 0 and not [str(w.message) for w in caught] and "Warning" not in err, err


def test_a_recorder_stopped_in_time_is_said_whole_up_to_its_stop(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A supervised recorder that did not finish in time is SIGINTed and, since fixer 81, exits
    130 with its footer written: the warning said "cut at its last flushed chunk" and sent the
    user to `--partial`, which such a file does not need."""
    from swarm.procs.fleet import recording_result

    assert recording_result("r.mcap", 130, tmp_path) == {"path": "r.mcap", "exit": 130,
                                                          "partial": True}
    err = capsys.readouterr().err
    assert "stopped before the run's end: r.mcap is partial, whole up to where it stopped" in err
    assert "--partial" not in err
