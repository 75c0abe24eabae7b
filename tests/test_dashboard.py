"""The dashboard's pure render functions, rendered into a capture console."""

from __future__ import annotations

import io

from rich.console import Console

from swarm.procs.dashboard import SwarmView, render, render_robots


def _view() -> SwarmView:
    v = SwarmView("demo", "nearest-frontier", 6, 8, 3, 10.0, episodes=2)
    v.apply_status({"ep": 0, "t": 1, "pos": [[0, 0], [2, 3], [5, 7]], "alive": [True, True, True],
                    "elratio": 0.42, "block_coll": 1, "robot_coll": 0, "dyn": [[4, 4]],
                    "timeouts": [], "static": [[1, 1], [1, 2]]}, now=0.0)
    v.apply_status({"ep": 0, "t": 2, "pos": [[0, 1], [2, 3], [5, 7]], "alive": [True, True, True],
                    "elratio": 0.5, "block_coll": 1, "robot_coll": 2, "dyn": [[4, 4], [3, 3]],
                    "timeouts": [2]}, now=0.1)
    for i in range(3):
        v.set_alive(i, True)
    v.apply_robot({"robot": 1, "msgs_in": 12, "msgs_out": 9, "latency_ms": 1.5, "bad": 3})
    return v


def _text(renderable: object, width: int = 140) -> str:
    console = Console(file=io.StringIO(), width=width, record=True, color_system=None)
    console.print(renderable)
    return console.export_text()


def test_dashboard_shows_grid_robots_and_figures() -> None:
    v = _view()
    text = _text(render(v))
    assert "demo" in text and "nearest-frontier" in text
    assert "0.500" in text  # elratio
    assert "block 1  robot 2" in text
    assert "ticks/s" in text and "10.0" in text  # two statuses 0.1 s apart
    assert "██" in text  # static / dynamic blocks drawn
    grid_rows = [line for line in text.splitlines() if "map 6x8" in line]
    assert grid_rows


def test_robot_table_counts_and_lost_robot() -> None:
    v = _view()
    v.set_alive(2, False)
    text = _text(render_robots(v))
    assert "lost" in text
    rows = {line.split("│")[1].strip(): line for line in text.splitlines() if line.count("│") > 2}
    cells = [c.strip() for c in rows["1"].split("│")]
    assert cells[2:10] == ["acting", "2,3", "12", "9", "1.5", "0", "3", "0"]
    assert "lost" in rows["2"]
    assert v.timeouts == 1


def test_learner_panel_shows_version_episodes_curve_and_traffic() -> None:
    v = _view()
    assert "learner" not in _text(render(v))
    v.learner = {"version": 7, "episodes": 70, "updates": 7, "ready": 3, "pending": 1,
                 "curve": [0.5, 0.6, 0.7], "last": {"loss": 0.0123}, "rollout_bytes_per_s": 4200.0,
                 "stale_used": 2, "stale_dropped": 1, "incomplete": 0, "bad": 0}
    text = _text(render(v))
    assert "weights version" in text and " 7" in text
    assert "70 (waiting 3, joining 1)" in text
    assert "▁▅█  0.700" in text  # the learning curve as a sparkline, last value
    assert "4200" in text and "0.0123" in text
    assert "used 2 (importance-weighted), dropped 1 (too old)" in text
    v.apply_robot({"robot": 2, "version": 6, "weights_bad": 1})
    assert "v6 (1 bad)" in _text(render_robots(v))


def test_the_last_episode_counts_and_a_dead_robot_draws_no_attention() -> None:
    """The episode counter reached K/K only when a next episode began (so never for the last):
    the result says how many completed. A lost robot's last attention line stayed drawn from
    its empty cell."""
    from swarm.procs.dashboard import attention_lines

    v = _view()
    assert v.episodes_done == 0
    v.apply_result({"completed": 2})
    assert v.episodes_done == 2 and "2/2" in _text(render(v))
    v.apply_result({"completed": "junk"})  # (a record that does not fit changes nothing)
    assert v.episodes_done == 2
    v.robots[2].final, v.robots[2].errors = True, 3  # its last status came: it left, not lost
    v.set_alive(2, False)
    assert v.robots[2].state == "done" and v.undecided() == [
        "robot 2 could not decide on 3 ticks and stayed in place there (`--log-dir DIR` keeps "
        "its log, with the reason)"]
    w = _view()
    w.apply_robot({"robot": 1, "stalls": 1, "rejoins": 1})
    assert w.stalled(set()) == ["robot 1 was stalled 1 time(s) and rejoined 1 time(s) (out of "
                                "the run meanwhile: its ticks there are not timeouts)"]
    assert w.stalled({1}) == []  # hung on purpose (--hang): no warning
    w.set_alive(0, True)
    w.set_alive(0, False)  # its token went before its last status: lost, then done (UA pass)
    assert w.robots[0].state == "lost"
    w.apply_robot({"robot": 0, "final": True, "msgs_in": 7, "wait_ms": 1.5})
    assert w.robots[0].state == "done" and w.robots[0].msgs_in == 7
    w.set_alive(1, True)  # its last status while its token is still up: done, not acting
    w.apply_robot({"robot": 1, "final": True})
    assert w.robots[1].state == "done"
    v.attention = {0: (2, [0.99, 9e-3, 1e-3]), 1: (2, [1e-4, 0.9999, 0.0])}
    assert attention_lines(v) == {}  # a weight of 1e-2 or less draws no line (UA pass)
    v.attention = {0: (2, [0.1, 0.9, 0.0]), 1: (2, [0.8, 0.2, 0.0])}
    assert attention_lines(v)  # the two lines (on the same cells)
    v.set_alive(1, False)
    assert 1 not in v.attention and attention_lines(v) == {}  # (0's line ended at robot 1)


def test_an_80_column_console_shows_the_robot_table_and_a_wide_map_stacks_the_panels() -> None:
    """At 80 columns the robot table had 35 characters for 11 columns (headers `…`, cells
    blank); a map wider than the console left the panels no width at all. Now the table keeps
    the columns it has room for, and the panels go below a map that leaves them none."""
    v = _view()
    text = _text(render(v), width=80)
    row = next(line for line in text.splitlines() if "acting" in line and "2,3" in line)
    assert "12" in row and "…" not in text  # id, state, pos, in: nothing cut to an ellipsis
    wide = SwarmView("big", "nearest-frontier", 40, 40, 3, 10.0, episodes=1)
    lines = _text(render(wide), width=80).splitlines()
    top = next(i for i, line in enumerate(lines) if "map 40x40" in line)
    assert any("swarm" in line for line in lines[top + 40:])  # below the map, not cut away


def _fitted_text(v: SwarmView, width: int, height: int) -> list[str]:
    console = Console(file=io.StringIO(), width=width, height=height, record=True,
                      color_system=None)
    console.print(render(v, fit=True))
    return console.export_text().splitlines()


def test_a_short_terminal_keeps_the_figures_and_robots_in_trouble_in_view() -> None:
    """At 80 x 24 a 20 x 20 swarm showed the map and the figures, and the live display cropped
    the robot table away (it needs ~40 rows). Fitted to the height, the figures that matter
    stay, the table keeps as many robots as fit (a lost one first) and says how many are not
    shown; an unfitted render (headless, a pipe) is whole."""
    v = SwarmView("demo", "commattn", 20, 20, 10, 10.0, episodes=3)
    v.apply_status({"ep": 0, "t": 4, "pos": [[i, i] for i in range(10)], "alive": [True] * 10,
                    "elratio": 0.3, "block_coll": 0, "robot_coll": 0, "dyn": [],
                    "timeouts": [], "static": [[0, 5]]}, now=0.0)
    for i in range(10):
        v.set_alive(i, True)
    v.set_alive(7, False)
    whole = _text(render(v), width=80).splitlines()
    assert len(whole) > 24 and "taller terminal" not in "\n".join(whole)
    lines = _fitted_text(v, 80, 24)
    text = "\n".join(lines)
    assert len(lines) <= 24, text
    assert "map 20x20" in text and "elratio" in text and "robots alive" in text
    assert "lost" in text  # robot 7, in trouble, is among the rows kept
    shown = [line for line in lines if "│ acting" in line or "│ lost" in line]
    assert shown and f"+{10 - len(shown)} robots (a taller terminal)" in text
    tall = _fitted_text(v, 80, 60)  # room for everything: nothing left out
    assert "taller terminal" not in "\n".join(tall) and sum("acting" in x for x in tall) == 9
    wide = SwarmView("big", "nearest-frontier", 40, 40, 3, 10.0, episodes=1)
    lines = _fitted_text(wide, 80, 24)  # a map taller than the terminal: figures above it
    top = next(i for i, line in enumerate(lines) if "map 40x40" in line)
    assert any("elratio" in line for line in lines[:top])


def test_message_rates_count_from_the_first_tick_live_and_replayed() -> None:
    """msgs/s counted the live processes' start-up (seconds before the first tick) while the
    replay counted from its first recorded message: the two views differed by tens of %. Both
    now count from the first status."""
    import time

    v = _view()  # its first status came at now=0.0 on the view's clock
    v.robots[0].msgs_out, v.robots[1].msgs_out, v.robots[2].msgs_out = 40, 30, 30
    v.started = time.monotonic() - 60.0  # a minute of start-up before the first tick
    v.first_status = time.monotonic() - 2.0
    assert "msgs/s          50" in _text(render(v))
    v.elapsed_s = 4.0  # a replay: recorded seconds since the first status
    assert "msgs/s          25" in _text(render(v))


def test_robots_not_up_at_the_first_tick_are_kept() -> None:
    """The run's first status names who was up when the world stopped waiting (`swarm run`
    warns about the others, `absent_at_start`); later statuses do not change it."""
    v = SwarmView("demo", "nearest-frontier", 6, 8, 3, 10.0, episodes=1)
    assert v.absent_at_start == []
    v.apply_status({"ep": 0, "t": 1, "pos": [[0, 0]] * 3, "alive": [True, False, True]}, now=0.0)
    v.apply_status({"ep": 0, "t": 2, "pos": [[0, 0]] * 3, "alive": [True, True, True]}, now=0.1)
    assert v.absent_at_start == [1]
