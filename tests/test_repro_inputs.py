"""`swarm repro`'s inputs checked in one line before any work (in-process: `swarm.cli.main`)."""

from __future__ import annotations

from pathlib import Path

import pytest
from conftest import ROOT

from swarm.cli import main


def refused(args: list[str], capsys: pytest.CaptureFixture[str]) -> str:
    """The one `swarm: error:` line of `swarm ARGS`, which must exit 2."""
    code = main(args)
    err = capsys.readouterr().err
    lines = err.rstrip("\n").splitlines()
    assert code == 2 and len(lines) == 1 and lines[0].startswith("swarm: error: "), err
    return lines[0]


@pytest.mark.parametrize(("curve", "says"), [
    (ROOT / "README.md", "is not a training curve"),
    (ROOT / "results" / "repro" / "comm.csv", "is not a training curve"),
    (ROOT / "checkpoints" / "commattn.pt", "is not a training curve (not a text file)"),
    (ROOT / "checkpoints", "Is a directory"),
], ids=["text", "other-csv", "binary", "folder"])
def test_repro_fig8_refuses_a_file_that_is_no_training_curve(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], curve: Path, says: str) -> None:
    """UA 64: another CSV or a text file was a ValueError traceback, a binary one a
    UnicodeDecodeError, a folder "not found"."""
    line = refused(["repro", "fig8", "--out", str(tmp_path / "o"), "--curve",
                    f"commattn={curve}"], capsys)
    assert says in line, line
    assert not (tmp_path / "o" / "fig8.csv").exists()


def test_repro_fig8_refuses_a_curve_of_no_policy_or_one_not_drawn(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """UA 64: `--curve bogus=FILE` was accepted, and the figure drawn without it."""
    shipped = ROOT / "checkpoints" / "vain_curve.csv"
    out = str(tmp_path / "o")
    line = refused(["repro", "fig8", "--out", out, "--curve", f"bogus={shipped}"], capsys)
    assert "--curve bogus=...: not a learned policy" in line, line
    line = refused(["repro", "fig8", "--out", out, "--policies", "commattn", "--curve",
                    f"vain={shipped}"], capsys)
    assert "vain is not among --policies commattn" in line, line


def test_repro_fig8_draws_a_second_curve_of_a_policy_as_name_tag(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """`--curve commattn:mine=FILE` draws your run beside the shipped commattn curve (one curve
    per policy name was all fig8 drew); the policy part is held like a plain name."""
    import csv

    shipped = ROOT / "checkpoints" / "commattn_curve.csv"
    out = tmp_path / "o"
    assert main(["repro", "fig8", "--out", str(out), "--policies", "commattn", "--curve",
                 f"commattn:mine={ROOT / 'checkpoints' / 'vain_curve.csv'}"]) == 0
    capsys.readouterr()
    rows = list(csv.DictReader((out / "fig8.csv").open()))
    assert [p for p in dict.fromkeys(r["policy"] for r in rows)] == ["commattn", "commattn:mine"]
    assert "| commattn:mine |" in (out / "fig8.md").read_text()
    for curve, says in ((f"bogus:x={shipped}", "--curve bogus:x=...: not a learned policy"),
                        (f"commattn:={shipped}", "--curve commattn:=...: not a learned policy"),
                        (f"vain:x={shipped}", "vain is not among --policies commattn")):
        line = refused(["repro", "fig8", "--out", str(tmp_path / "p"), "--policies", "commattn",
                        "--curve", curve], capsys)
        assert says in line, line


@pytest.mark.parametrize("flag", ["--curve", "--checkpoint"])
def test_repro_refuses_a_name_given_twice(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                          flag: str) -> None:
    """UA 64: `--curve commattn=A --curve commattn=B` kept B without a word."""
    given = ROOT / "checkpoints" / ("commattn_curve.csv" if flag == "--curve" else "commattn.pt")
    line = refused(["repro", "fig8", "--policies", "commattn", "--out", str(tmp_path / "o"),
                    flag, f"commattn={given}", flag, f"commattn={given}"], capsys)
    assert f"{flag} commattn=... given 2 times" in line, line
    if flag == "--checkpoint":  # the parser eval and bench policy share, too
        line = refused(["eval", "--policy", "commattn", "--episodes", "1", flag,
                        f"commattn={given}", flag, f"commattn={given}"], capsys)
        assert f"{flag} commattn=... given 2 times" in line, line


def test_repro_comm_refuses_world_flags_its_conditions_set(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """UA 64: `repro comm --comm-range 3` ran the row labelled "range 10 (default)" at range 3;
    `--horizon 10` shortened the 20 x 20 rows only."""
    for flag in (["--comm-range", "3"], ["--horizon", "10"], ["--size", "30x30"],
                 ["--static-blocks", "5"]):
        line = refused(["repro", "comm", "--out", str(tmp_path / "o"), *flag], capsys)
        assert f"{flag[0]} is not used by comm (comm: its conditions set" in line, line


def test_repro_comm_labels_say_the_world_each_row_ran(tmp_path: Path) -> None:
    """A world with another comm range or horizon (`repro all --comm-range 3`, a config's
    [world]) serves the other items; comm's rows run what their labels say, named unused."""
    from swarm.studies.comm import comm
    from world.config import WorldConfig, replace

    res = comm(replace(WorldConfig(), comm_range=3.0, horizon=10), tmp_path, "test", 0, 1,
               policies=("random",), batch=1)
    row = {r["condition"]: r for r in res["rows"]}
    assert row["range 10 (default)"]["comm_range"] == 10.0, row["range 10 (default)"]
    assert row["loss 50%"]["comm_range"] == 10.0 and row["loss 50%"]["horizon"] == 30
    assert row["40 x 40, 20 robots"]["horizon"] == 60
    md = (tmp_path / "comm.md").read_text()
    assert "The world's horizon 10, comm_range 3 are not used" in md, md


def test_repro_comm_refuses_a_policy_named_twice(tmp_path: Path,
                                                 capsys: pytest.CaptureFixture[str]) -> None:
    """UA 64: `--comm-policies commattn,commattn` was one column without a word."""
    line = refused(["repro", "comm", "--out", str(tmp_path / "o"), "--comm-policies",
                    "commattn,random,commattn"], capsys)
    assert "--comm-policies names commattn twice" in line, line


def test_repro_table2_rows_name_their_checkpoint(tmp_path: Path,
                                                 capsys: pytest.CaptureFixture[str]) -> None:
    """UA 64: table2.json's rows had no `checkpoint` (comm.csv's have one per row)."""
    import json

    from swarm.cli import main

    given = tmp_path / "mine.pt"
    given.write_bytes((ROOT / "checkpoints" / "vain.pt").read_bytes())
    assert main(["repro", "table2", "--out", str(tmp_path), "--policies", "vain,random",
                 "--table2-episodes", "2", "--checkpoint", f"vain={given}"]) == 0
    rows = json.loads((tmp_path / "table2.json").read_text())["rows"]
    assert [r["checkpoint"] for r in rows] == [str(given), ""], rows
    md = (tmp_path / "table2.md").read_text()  # (UA 64: "the last column", with a gap after)
    assert "Column `vain - this (paired)` is vain's elratio minus the row's" in md, md
    assert "vain - this (paired)" in capsys.readouterr().out  # (the terminal had no such column)


def test_table2_says_what_its_rows_and_columns_are() -> None:
    """UA 64: with --table2-episodes 10 the oracle's note said "first 60 episodes only"; the
    terminal table had no paired column, no gap column and no `*` marks."""
    from io import StringIO

    from rich.console import Console

    from swarm.cli.console import table2_table
    from swarm.studies.repro import ReproConfig, table2_notes

    base = {"robots": 10, "reward_mean": -1.0, "collisions_mean": 0.5,
            "block_collisions_mean": 0.25, "elratio_std": 0.01, "success_rate": 0.5,
            "paper_reward": None, "first_minus_elratio_se": 0.01}
    rows = [{**base, "policy": "commattn", "episodes": 10, "decentralized": True,
             "elratio_mean": 0.9, "first_minus_elratio": 0.0, "gap_closed": 0.8},
            {**base, "policy": "random", "episodes": 10, "decentralized": True,
             "elratio_mean": 0.7, "first_minus_elratio": 0.2, "gap_closed": 0.0},
            {**base, "policy": "oracle", "episodes": 10, "decentralized": False,
             "elratio_mean": 0.95, "first_minus_elratio": -0.05, "gap_closed": 1.0}]
    notes = table2_notes(rows, ReproConfig(table2_episodes=10))
    assert "(first 10 episodes only)" in notes, notes
    buf = StringIO()
    Console(file=buf, width=200).print(table2_table(rows))
    shown = buf.getvalue()
    for words in ("commattn - this (paired)", "gap", "oracle *", "80.0%", "-0.0500",
                  "* not decentralized"):
        assert words in shown, shown


def test_repro_help_says_the_default_policies_of_each_item(
        capsys: pytest.CaptureFixture[str]) -> None:
    """UA 64: the help said "the four learned, three frontier and random", but Table 2's default
    run adds the planners."""
    with pytest.raises(SystemExit):
        main(["repro", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "Table 2 then adds team-beam, chain-plan, central and oracle" in text, text


def test_a_policy_written_twice_is_refused_as_a_typo(tmp_path: Path,
                                                     capsys: pytest.CaptureFixture[str]) -> None:
    """UA pass 66: `eval --policy random,random` and `repro table2 --policies random,random` ran
    one row without a word where `bench swarm` and `--comm-policies` refused the repeat; `all`
    with a baseline it also brings still runs that baseline once."""
    for args in (["eval", "--policy", "random,random", "--episodes", "1"],
                 ["repro", "table2", "--out", str(tmp_path / "o"), "--policies",
                  "random,nearest-frontier,random", "--table2-episodes", "1"]):
        line = refused(args, capsys)
        assert "policy 'random' is named 2 times: each policy runs once" in line, line
    from swarm.common.policy_spec import resolve_policies

    assert resolve_policies("all,random").count("random") == 1


@pytest.mark.parametrize("item,args", [
    ("fig4", ["--episodes", "1", "--robots", "2"]),
    ("fig5", ["--episodes", "1", "--add-every", "3"]),
    ("table1", ["--decisions", "2"]),
], ids=["fig4", "fig5", "table1"])
def test_every_repro_item_names_the_checkpoints_it_ran(tmp_path: Path, item: str,
                                                       args: list[str]) -> None:
    """UA 75: fig4.json, fig4.csv and fig4.md named no checkpoint (the Made by line only the
    command); every item's JSON now has `checkpoints`, each row a `checkpoint` (empty for a
    policy without weights) and the Made by line names them, a shipped one relative to the
    repository."""
    import json

    given = tmp_path / "mine.pt"
    given.write_bytes((ROOT / "checkpoints" / "commattn.pt").read_bytes())
    assert main(["repro", item, "--out", str(tmp_path), "--policies", "commattn,vain,random",
                 "--checkpoint", f"commattn={given}", *args]) == 0
    data = json.loads((tmp_path / f"{item}.json").read_text())
    assert data["checkpoints"] == {"commattn": [str(given)], "vain": ["checkpoints/vain.pt"]}
    assert {(r["policy"], r["checkpoint"]) for r in data["rows"]} == {
        ("commattn", str(given)), ("vain", "checkpoints/vain.pt"), ("random", "")}
    assert "checkpoint" in (tmp_path / f"{item}.csv").read_text().splitlines()[0].split(",")
    md = (tmp_path / f"{item}.md").read_text()
    assert f"Checkpoints: commattn `{given}`; vain `checkpoints/vain.pt`." in md, md[:600]


@pytest.mark.parametrize("args,says", [
    (["fig4", "--policies", "commattn"], "is not among --policies commattn"),
    (["fig9", "--policies", "commattn"], "is not among --policies commattn"),
    (["fig10"], "is not among fig10's policy commattn"),
    (["comm", "--comm-policies", "commattn,random"], "is not among --comm-policies "
                                                     "commattn,random"),
    (["fig8", "--policies", "commattn"], "is not among the policies fig8 runs (none)"),
    (["all", "--policies", "commattn,random"], "is not among the policies table1, table2, "
                                               "fig4, fig5, fig8, fig9, fig10, fig11, comm run"),
], ids=["fig4", "fig9", "fig10", "comm", "fig8", "all"])
def test_repro_refuses_a_checkpoint_of_a_policy_it_does_not_run(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], args: list[str], says: str) -> None:
    """UA 75: `repro fig4 --policies commattn --checkpoint commnet=FILE` exited 0 and its Made
    by line named a checkpoint that played no part (`eval` refuses one); items that choose their
    own policies (fig9, fig10, comm) are checked against those."""
    tiny = tmp_path / "tiny.toml"  # (budgets that keep a run that is not refused short)
    tiny.write_text("[repro]\nepisodes = 1\nrobots = [2]\ndecisions = 1\ntable2_episodes = 1\n"
                    "comm_episodes = 1\nfig9_episodes = 1\nfig10_episodes = 1\n"
                    "fig11_episodes = 1\noracle_episodes = 1\nadd_every = [3]\n")
    line = refused(["repro", *args, "--out", str(tmp_path / "o"), "--config", str(tiny),
                    "--checkpoint", f"commnet={ROOT / 'checkpoints' / 'commnet.pt'}"], capsys)
    assert f"--checkpoint commnet=...: 'commnet' {says}" in line, line
    assert not (tmp_path / "o").exists()


def test_an_interrupted_item_leaves_none_of_its_old_files_beside_new_ones(tmp_path: Path) -> None:
    """`swarm repro ITEM --out DIR` stopped part-way over an earlier output left a mixed set
    (new fig8.csv and .md beside the old .png and .json). An item's old files now go when it
    starts (its new ones come at its end), with the temp files a killed repro of it left; here
    it is stopped (Ctrl-C) during its work. Another item's files and temp files stay."""
    from swarm.studies.repro import ReproConfig, run
    from world.config import WorldConfig

    out = tmp_path / "out"
    out.mkdir()
    old = [out / f"fig4.{ext}" for ext in ("csv", "md", "png", "json")]
    stale = out / ".fig4.png.x7k2q_1b.tmp"
    others = [out / "table2.csv", out / ".table2.csv.a1b2c3.tmp"]
    for f in (*old, stale, *others):
        f.write_text("an earlier run's")

    class Stopped:  # a progress sink: Ctrl-C during the item's first point
        def start(self, label: str, total: int) -> None:
            pass

        def advance(self, n: int = 1) -> None:
            raise KeyboardInterrupt

    cfg = ReproConfig(out=str(out), policies=("random",), robots=(2,), episodes=2, batch=1)
    with pytest.raises(KeyboardInterrupt):
        run(["fig4"], WorldConfig(n_robots=2), cfg, "swarm repro fig4", Stopped())
    assert [f.name for f in (*old, stale) if f.exists()] == []
    assert all(f.read_text() == "an earlier run's" for f in others)
    res = run(["fig4"], WorldConfig(n_robots=2), cfg, "swarm repro fig4")  # whole: all four
    assert res["fig4"]["files"] == [str(f) for f in old] and all(f.is_file() for f in old)
