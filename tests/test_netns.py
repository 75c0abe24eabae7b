"""Kernel-level realism (`swarm run --netns`): real namespaces, veths, tc and iptables."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
from pathlib import Path

import pytest
from conftest import swarm

from swarm.net.kernel.netns import NetnsConfig, Topology, namespaces
from world.config import ConfigError


def _netns_reason() -> str | None:
    if os.geteuid() != 0:
        return "needs root (network namespaces)"
    if shutil.which("ip") is None:
        return "`ip` (iproute2) is not installed"
    p = subprocess.run(["ip", "netns", "list"], capture_output=True, text=True)
    return None if p.returncode == 0 else f"`ip netns` unavailable: {p.stderr.strip()}"


REASON = _netns_reason()
pytestmark = pytest.mark.skipif(REASON is not None, reason=REASON or "")




def ours(run_id: str) -> list[str]:
    return [ns for ns in namespaces() if ns.startswith(f"swarm-{run_id}-")]


def link_exists(name: str) -> bool:
    return subprocess.run(["ip", "link", "show", name], capture_output=True).returncode == 0


@pytest.mark.procs
def test_topology_up_down_leaves_no_namespace_behind() -> None:
    topo = Topology("nsupdown", 2, NetnsConfig(bandwidth=8000.0))
    with topo:
        assert sorted(ours("nsupdown")) == ["swarm-nsupdown-r0", "swarm-nsupdown-r1",
                                            "swarm-nsupdown-w"]
        assert link_exists(topo.host_if) and len(topo.host_if) <= 15
        qdisc = subprocess.run(["tc", "-n", topo.robot_ns[0], "qdisc", "show"],
                               capture_output=True, text=True).stdout
        assert "tbf" in qdisc and "64Kbit" in qdisc  # 8000 B/s
    assert ours("nsupdown") == [] and not link_exists(topo.host_if)
    with pytest.raises(RuntimeError, match="boom"), Topology("nsboom", 1):
        assert ours("nsboom")
        raise RuntimeError("boom")
    assert ours("nsboom") == []  # teardown ran on the failure too


@pytest.mark.procs
def test_a_namespace_that_exists_already_is_refused_and_left_alone() -> None:
    subprocess.run(["ip", "netns", "add", "swarm-nsclash-w"], check=True)
    try:
        with pytest.raises(ConfigError, match="exists already"):
            Topology("nsclash", 1).up()
        assert ours("nsclash") == ["swarm-nsclash-w"]
    finally:
        subprocess.run(["ip", "netns", "del", "swarm-nsclash-w"], check=True)


@pytest.mark.procs
def test_a_run_refused_by_a_namespace_of_its_id_leaves_no_temp_folder(tmp_path: Path) -> None:
    """`swarm run --netns` refused because a namespace of its id exists: one line, exit 2, and
    nothing in the temp dir (its spec.json was left in a temp folder; UA pass 43)."""
    subprocess.run(["ip", "netns", "add", "swarm-nsleft-w"], check=True)
    try:
        r = swarm("run", "--netns", "--run-id", "nsleft", "--robots", "2", "--episodes", "1",
                  "--headless", env={"TMPDIR": str(tmp_path)}, timeout=60)
    finally:
        subprocess.run(["ip", "netns", "del", "swarm-nsleft-w"], check=True)
    assert r.returncode == 2 and "exists already" in r.stderr, r.stderr
    assert [p.name for p in tmp_path.iterdir()] == ["swarm-runs"], list(tmp_path.rglob("*"))
    assert ours("nsleft") == []


@pytest.mark.procs
def test_bad_use_is_a_one_line_error() -> None:
    r = swarm("run", "--headless", "--robots", "2", "--kernel-loss", "0.1")
    assert r.returncode != 0 and "need --netns" in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1
    with pytest.raises(ConfigError, match="kernel loss"):
        NetnsConfig.parse(loss="lots")


@pytest.mark.procs
def test_netns_run_takes_the_same_actions_as_loopback(tmp_path: Path) -> None:
    common = ["run", "--headless", "--robots", "2", "--episodes", "1", "--policy",
              "nearest-frontier", "--seed", "5"]
    plain = swarm(*common, "--run-id", "nsplain", "--json", str(tmp_path / "a.json"))
    kern = swarm(*common, "--netns", "--run-id", "nskern", "--json", str(tmp_path / "b.json"))
    assert plain.returncode == 0, plain.stderr
    assert kern.returncode == 0, kern.stderr
    a, b = (json.loads((tmp_path / f).read_text()) for f in ("a.json", "b.json"))
    assert b["netns"]["world_ns"] == "swarm-nskern-w"
    assert a["actions"] == b["actions"]
    assert b["timeouts"] == 0 and b["robots_lost"] == 0
    assert b["messages"]["late"] == b["messages"]["stale"] == 0
    assert ours("nskern") == []
    # --delivery direct: the robots time their copies on their own wall clocks in namespaces
    direct = swarm(*common, "--netns", "--delivery", "direct", "--run-id", "nsdir", "--json",
                   str(tmp_path / "d.json"))
    assert direct.returncode == 0, direct.stderr
    d = json.loads((tmp_path / "d.json").read_text())
    assert d["actions"] == a["actions"] and d["delivery"] == "direct" and d["clock"] == "real"
    assert d["messages"]["late"] == d["messages"]["stale"] == 0
    assert d["messages"]["reported"] == [0, 1]
    assert ours("nsdir") == []

    # --secure: TLS on every veth, the world's certificate issued for the run's addresses
    pytest.importorskip("cryptography")
    from swarm.net.security.certs import make_certs

    make_certs(tmp_path / "certs", robots=2)
    sec = swarm(*common, "--netns", "--secure", str(tmp_path / "certs"), "--run-id", "nssec",
                "--json", str(tmp_path / "c.json"), "--log-dir", str(tmp_path / "nssec"))
    assert sec.returncode == 0, sec.stderr
    c = json.loads((tmp_path / "c.json").read_text())
    assert c["actions"] == a["actions"] and c["timeouts"] == 0 and c["messages"]["bad"] == 0
    assert c["secure"]["hub"].startswith(f"tls/{c['netns']['hub_addr']}:")
    assert (tmp_path / "nssec" / "zenoh" / "run-certs" / "world.pem").exists()
    assert ours("nssec") == []
    udp = swarm(*common, "--netns", "--netns-transport", "udp", "--secure",
                str(tmp_path / "certs"))
    assert udp.returncode == 2 and "tcp" in udp.stderr and udp.stderr.count("\n") == 1


@pytest.mark.procs
@pytest.mark.skipif(shutil.which("iptables") is None, reason="iptables is not installed")
def test_kernel_loss_makes_messages_late_or_robots_lost(tmp_path: Path) -> None:
    """TCP turns dropped packets into retransmission delay: late messages and missed ticks,
    and past the 1 s Zenoh lease, closed sessions (robots lost, or none joining at all). The
    radio itself loses nothing."""
    conf = tmp_path / "run.toml"
    conf.write_text("[run]\nstart_timeout = 6.0\n")
    damage = {}
    for loss in ("0", "0.3"):
        out = tmp_path / f"{loss}.json"
        r = swarm("run", "--config", str(conf), "--headless", "--robots", "2", "--episodes", "1",
                  "--policy", "nearest-frontier", "--tick-timeout", "0.5", "--netns",
                  "--kernel-loss", loss, "--run-id", f"nsloss{loss.replace('.', '')}",
                  "--json", str(out))
        if loss != "0" and r.returncode != 0:  # no session survived long enough to join
            assert "no robot came alive" in r.stderr, r.stderr
            damage[loss] = 2
            continue
        assert r.returncode == 0, r.stderr
        res = json.loads(out.read_text())
        assert res["messages"]["lost"] == 0  # the radio drops nothing
        damage[loss] = (res["messages"]["late"] + res["messages"]["stale"] + res["timeouts"]
                        + res["robots_lost"]
                        + res["netns"]["never_joined"])
    assert damage["0"] == 0 and damage["0.3"] > 0, damage
    assert ours("nsloss0") == [] and ours("nsloss03") == []


@pytest.mark.procs
@pytest.mark.skipif(shutil.which("iptables") is None, reason="needs iptables (kernel loss)")
def test_a_kernel_sweeps_failed_run_keeps_its_logs_beside_the_csv(tmp_path: Path) -> None:
    """A kernel sweep's run that never started (no robot up within the start timeout) is a row
    with its error, and its logs go beside the CSV as every kept run's do (they stayed in /tmp,
    named only in a line on stderr)."""
    import csv

    sweep = tmp_path / "s.toml"
    sweep.write_text("[world]\nn_robots = 2\n[run]\nepisodes = 1\nstart_timeout = 2.0\n"
                     "[experiment]\nname = \"kfail\"\nparameter = \"loss\"\nkernel = true\n"
                     "values = [0.97]\npolicies = [\"nearest-frontier\"]\nseeds = [0]\n")
    r = swarm("experiment", str(sweep), "--out", str(tmp_path / "o"), timeout=240)
    rows = list(csv.DictReader((tmp_path / "o" / "kfail.csv").open()))
    assert len(rows) == 1 and "no robot came alive" in rows[0]["error"], (rows, r.stderr)
    logs = tmp_path / "o" / "kfail-0-logs"
    assert (logs / "world.log").is_file(), r.stderr
    assert f"logs in {logs}" in r.stderr
    assert "| nearest-frontier | 0.97 | no run played (1 failed: `error` in the CSV) |" in (
        tmp_path / "o" / "kfail.md").read_text()  # (it said "nan ± - | nan | nan | nan")
