"""The live dashboard: pure render functions from a `SwarmView` to rich renderables.

Nothing here opens a session or blocks; the supervisor feeds `SwarmView.apply_*` with the
records it receives and `Live(get_renderable=...)` calls `render`.
"""

from __future__ import annotations

import time
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any

from rich.console import Console, ConsoleOptions, Group, RenderResult
from rich.measure import Measurement
from rich.panel import Panel
from rich.table import Table
from rich.text import Text

ROBOT_STYLES = ("bold red", "bold green", "bold yellow", "bold blue", "bold magenta", "bold cyan")


@dataclass
class RobotRow:
    state: str = "starting"
    pos: tuple[int, int] | None = None
    msgs_in: int = 0
    msgs_out: int = 0
    latency_ms: float = 0.0
    bad: int = 0
    missed: int = 0  # ticks whose bundle did not come in time
    missed_hidden: int = 0  # ticks whose predecessor's hidden-state message did not come
    bytes_out: int = 0
    alive: bool = False
    restarts: int = 0
    version: int = 0  # weights version in use (swarm run --train)
    weights_bad: int = 0
    weights_late: int = 0  # train_sync episodes it began without the version the world named
    stalls: int = 0  # times the robot found itself stopped or starved (SIGSTOP, overload)
    rejoins: int = 0  # times it rejoined after its session dropped
    errors: int = 0  # ticks it could not decide on (skipped)
    compute_ms: float = 0.0  # mean planning time per decision, waits excluded
    wait_ms: float = 0.0  # mean time per decision waiting for the bundle and the predecessor
    stale: int = 0  # messages of a tick already past (or kept for one that passed)
    oversized: int = 0  # payloads over the inbox's bound, dropped unread
    overflow: int = 0  # events past the inbox queue's bound, dropped
    final: bool = False  # these are its counts at the run's end (its last status), not a snapshot

    COUNTERS = ("msgs_in", "msgs_out", "bad", "missed", "missed_hidden", "version", "weights_bad",
                "weights_late", "stalls", "rejoins", "errors", "stale", "oversized", "overflow")

    def counters(self) -> dict[str, int]:
        """What a run's result reports of this robot (`robot_status`)."""
        return {**{k: getattr(self, k) for k in self.COUNTERS}, "final": self.final}


@dataclass
class SwarmView:
    """Everything the dashboard shows, accumulated from status records."""

    run_id: str
    policy: str
    height: int
    width: int
    n_robots: int
    comm_range: float
    episodes: int
    static: set[tuple[int, int]] = field(default_factory=set)
    dynamic: set[tuple[int, int]] = field(default_factory=set)
    explored: set[tuple[int, int]] = field(default_factory=set)
    robots: dict[int, RobotRow] = field(default_factory=dict)
    ep: int = -1
    tick: int = 0
    elratio: float = 0.0
    block_coll: int = 0
    robot_coll: int = 0
    ticks_done: int = 0
    absent_at_start: list[int] = field(default_factory=list)  # robots not up at the first tick
    started: float = field(default_factory=time.monotonic)
    tick_times: list[float] = field(default_factory=list)
    world_alive: bool = False
    timeouts: int = 0
    bad: int = 0
    late: int = 0
    episodes_done: int = 0
    faults: list[str] = field(default_factory=list)  # link faults in force (from the world)
    events: list[str] = field(default_factory=list)  # process faults applied (supervisor)
    links: dict[str, list[int]] = field(default_factory=dict)  # "a-b": delivered, dropped, late,
    # queued
    radio: dict[str, int] = field(default_factory=dict)
    learner: dict[str, Any] | None = None  # the learner's last status (swarm run --train)
    heard_links: int = 0  # robot pairs the radio delivered between in the last tick
    clock: str = "real"  # the run's clock (status records say which)
    vtime: float = 0.0  # virtual seconds since the run started (virtual clock)
    bad_records: int = 0  # status records the supervisor dropped (did not fit their schema)
    attention: dict[int, tuple[int, list[float]]] = field(default_factory=dict)
    """Robot -> (tick, its attention weights over the team), from robot statuses (CommAttn)."""
    attention_focus: int | None = -1
    """Whose strongest attention the map draws: -1 every robot's, k robot k's, None nobody's."""
    replay: str = ""
    """What is replayed (a recording, its speed and position); empty on a live run."""
    elapsed_s: float | None = None
    """Replay: the recorded seconds since the first tick's status (live: wall time since it)."""
    first_status: float | None = None
    """When the first status came (`apply_status`'s clock): msgs/s and bytes/s count from the
    first tick, live and replayed alike (the live view had counted its processes' start-up)."""

    def __post_init__(self) -> None:
        for i in range(self.n_robots):
            self.robots.setdefault(i, RobotRow())

    def apply_status(self, rec: dict[str, Any], now: float | None = None) -> None:
        """A world status record (one per tick)."""
        now = time.monotonic() if now is None else now
        if self.first_status is None:
            self.first_status = now
            self.absent_at_start = [i for i, a in enumerate(rec.get("alive", [])) if not a]
        if rec.get("ep") != self.ep:
            if self.ep >= 0:
                self.episodes_done += 1
            self.ep = int(rec.get("ep", 0))
            self.explored.clear()
            self.dynamic.clear()
            self.attention.clear()
        if "static" in rec:
            self.static = {tuple(c) for c in rec["static"]}  # type: ignore[misc]
        self.tick = int(rec.get("t", 0))
        self.elratio = float(rec.get("elratio", 0.0))
        self.block_coll = int(rec.get("block_coll", 0))
        self.robot_coll = int(rec.get("robot_coll", 0))
        self.dynamic = {tuple(c) for c in rec.get("dyn", [])}  # type: ignore[misc]
        self.bad = int(rec.get("bad", 0))
        self.late = int(rec.get("late", 0))
        self.timeouts += len(rec.get("timeouts", []))
        self.faults = list(rec.get("faults", self.faults))
        self.links = dict(rec.get("links", self.links))
        self.radio = dict(rec.get("radio", self.radio))
        self.heard_links = int(rec.get("heard_links", 0))
        self.clock = str(rec.get("clock", self.clock))
        self.vtime = float(rec.get("vtime", 0.0))
        for i, (p, alive) in enumerate(zip(rec.get("pos", []), rec.get("alive", []),
                                           strict=False)):
            row = self.robots.setdefault(i, RobotRow())
            row.pos = (int(p[0]), int(p[1]))
            if alive:
                self.explored.add(row.pos)
        self.ticks_done += 1
        self.tick_times = (self.tick_times + [now])[-20:]

    def apply_robot(self, rec: dict[str, Any]) -> None:
        row = self.robots.setdefault(int(rec.get("robot", -1)), RobotRow())
        for k in (*RobotRow.COUNTERS, "bytes_out"):  # (range-checked: check_robot_status)
            setattr(row, k, int(rec.get(k, 0)))
        for k in ("latency_ms", "compute_ms", "wait_ms"):
            setattr(row, k, float(rec.get(k, 0.0)))
        row.final = rec.get("final") is True
        if row.final:  # its last status: it is leaving the ended run (its token may go
            row.state = "done"  # before or after this comes, or not be seen going at all)
        if isinstance(rec.get("attn"), list):  # range-checked by records.check_robot_status
            self.attention[int(rec["robot"])] = (int(rec.get("attn_t", 0)),
                                                 [float(x) for x in rec["attn"]])

    def undecided(self) -> list[str]:
        """A line for each robot that could not decide on some ticks (a policy's error)."""
        return [f"robot {i} could not decide on {r.errors} ticks and stayed in place there "
                "(`--log-dir DIR` keeps its log, with the reason)"
                for i, r in sorted(self.robots.items()) if r.errors]

    def stalled(self, planned: set[int]) -> list[str]:
        """A line for each robot but `planned` (hung on purpose) that was stopped or starved
        mid-run (SIGSTOP, overload): its session may have dropped, and the world then played on
        without it until it rejoined."""
        return [f"robot {i} was stalled {r.stalls} time(s) and rejoined {r.rejoins} time(s) "
                "(out of the run meanwhile: its ticks there are not timeouts)"
                for i, r in sorted(self.robots.items())
                if (r.stalls or r.rejoins) and i not in planned]

    def final(self, robots: Iterable[int]) -> bool:
        """Whether each of `robots` has sent its last status (its counts at the run's end)."""
        return all(self.robots.get(i, RobotRow()).final for i in robots)

    def strongest(self) -> dict[int, tuple[int, float]]:
        """Robot -> (the other member it attends to most, weight), for robots reporting
        attention that heard someone besides themselves."""
        out = {}
        for i, (_, w) in self.attention.items():
            others = [(x, j) for j, x in enumerate(w) if j != i and x > 0]
            if others:
                x, j = max(others)
                out[i] = (j, x)
        return out

    def set_alive(self, robot: int, alive: bool) -> None:
        row = self.robots.setdefault(robot, RobotRow())
        if alive and not row.alive and row.state == "lost":
            row.restarts += 1
        row.alive = alive
        row.state = "acting" if alive else "done" if row.final else \
            "lost" if row.state != "starting" else "starting"  # (done: left after the run)
        if not alive:  # a dead robot's last attention is not drawn on (it came back: anew)
            self.attention.pop(robot, None)

    def apply_result(self, res: dict[str, Any]) -> None:
        """The run's result: its completed episodes (a status only says an episode is done
        when the next one starts, so the last one was never counted)."""
        done = res.get("completed")
        if isinstance(done, int) and not isinstance(done, bool) and 0 <= done <= self.episodes:
            self.episodes_done = max(self.episodes_done, done)

    @property
    def ticks_per_s(self) -> float:
        if len(self.tick_times) < 2:
            return 0.0
        span = self.tick_times[-1] - self.tick_times[0]
        return (len(self.tick_times) - 1) / span if span > 0 else 0.0


def line_cells(a: tuple[int, int], b: tuple[int, int]) -> list[tuple[int, int]]:
    """The grid cells strictly between a and b on a straight line (Bresenham)."""
    (y0, x0), (y1, x1) = a, b
    dy, dx = abs(y1 - y0), abs(x1 - x0)
    sy, sx = (1 if y1 > y0 else -1), (1 if x1 > x0 else -1)
    err, out = dx - dy, []
    y, x = y0, x0
    while (y, x) != (y1, x1):
        e2 = 2 * err
        if e2 > -dy:
            err -= dy
            x += sx
        if e2 < dx:
            err += dx
            y += sy
        out.append((y, x))
    return out[:-1]


def attention_lines(v: SwarmView) -> dict[tuple[int, int], int]:
    """Cell -> robot whose line to the member it attends to most crosses it (focus applied)."""
    marks: dict[tuple[int, int], int] = {}
    if v.attention_focus is None:
        return marks
    for i, (j, x) in sorted(v.strongest().items()):
        if x < ATTN_LINE_MIN:  # (the shipped CommAttn gives others ~1e-4: no line for that)
            continue
        a, b = v.robots.get(i), v.robots.get(j)
        if v.attention_focus not in (-1, i) or a is None or b is None or a.pos is None \
                or b.pos is None or not (a.alive and b.alive):
            continue
        for c in line_cells(a.pos, b.pos):
            marks.setdefault(c, i)
    return marks


def render_grid(v: SwarmView) -> Text:
    """The map: static blocks, dynamic blocks, explored cells, robots by id, and a dotted line
    from each robot to the member it attends to most (CommAttn), in the robot's colour, when
    that member gets at least ATTN_LINE_MIN of its attention."""
    at: dict[tuple[int, int], list[int]] = {}
    for i, row in v.robots.items():
        if row.pos is not None and row.alive:
            at.setdefault(row.pos, []).append(i)
    marks = attention_lines(v)
    text = Text()
    for y in range(v.height):
        for x in range(v.width):
            c = (y, x)
            if c in at:
                ids = at[c]
                label = str(ids[0] % 10) if len(ids) == 1 else "*"
                text.append(label + " ", style=ROBOT_STYLES[ids[0] % len(ROBOT_STYLES)])
            elif c in v.static:
                text.append("██", style="grey50")
            elif c in v.dynamic:
                text.append("██", style="dark_orange")
            elif c in marks:
                text.append("∙∙", style=ROBOT_STYLES[marks[c] % len(ROBOT_STYLES)])
            elif c in v.explored:
                text.append("· ", style="green")
            else:
                text.append("  ")
        text.append("\n")
    return text


ATTN_LINE_MIN = 0.05  # the least attention weight the map draws a line for

ROBOT_COLUMNS = (("id", 0), ("state", 0), ("pos", 0), ("in", 0), ("out", 0), ("lat ms", 70),
                 ("missed", 45), ("bad", 45), ("restarts", 70), ("compute ms", 90),
                 ("wait ms", 90))
"""The robot table's columns and the width (characters) below which each is left out."""


def render_robots(v: SwarmView, width: int | None = None, rows: int | None = None) -> Table:
    """One row per robot; on a narrow console (`width`) only the columns that fit; with `rows`,
    at most that many (robots in trouble first) and a caption counting the others."""
    table = Table(title="robots", expand=True, pad_edge=False)
    shown = sorted(v.robots)
    if rows is not None and rows < len(shown):
        trouble = lambda i: (v.robots[i].alive and not v.robots[i].missed  # noqa: E731
                             and not v.robots[i].missed_hidden
                             and not v.robots[i].bad, i)
        shown = sorted(sorted(shown, key=trouble)[:max(rows, 0)])
        table.caption = f"+{len(v.robots) - len(shown)} robots (a taller terminal)"
    cols = [c for c, need in ROBOT_COLUMNS if width is None or width >= need]
    if v.learner is not None and (width is None or width >= 90):  # field training: the
        cols += ["weights"]  # weights version each robot acts with
    for col in cols:
        table.add_column(col, justify="right" if col not in ("state",) else "left")
    for i in shown:
        r = v.robots[i]
        cell = {"id": str(i), "state": Text(r.state, style="green" if r.alive else "red"),
                "pos": "-" if r.pos is None else f"{r.pos[0]},{r.pos[1]}",
                "in": str(r.msgs_in), "out": str(r.msgs_out), "lat ms": f"{r.latency_ms:.1f}",
                "missed": f"{r.missed}" + (f" h{r.missed_hidden}" if r.missed_hidden else ""),
                "bad": str(r.bad), "restarts": str(r.restarts),
                "compute ms": f"{r.compute_ms:.1f}", "wait ms": f"{r.wait_ms:.1f}",
                "weights": f"v{r.version}" + (f" ({r.weights_bad} bad)" if r.weights_bad
                                              else "")}
        table.add_row(*(cell[c] for c in cols))
    return table


RADIO_COUNTS = ("lost", "cut", "late", "queued", "dropped_bw")
COMPACT_FIGURES = ("replay", "policy", "episode", "tick", "elratio", "collisions", "timeouts",
                   "bad / late", "robots alive", "faults", "radio", "process faults")
"""The figures a short terminal keeps (`render_figures(compact=True)`)."""


def render_figures(v: SwarmView, compact: bool = False) -> Table:
    table = Table.grid(padding=(0, 2))
    table.add_column(style="bold")
    table.add_column()
    since = v.started if v.first_status is None else v.first_status
    elapsed = max(time.monotonic() - since if v.elapsed_s is None else v.elapsed_s, 1e-9)
    rows = [
        *([("replay", v.replay)] if v.replay else []),
        ("run", v.run_id), ("policy", v.policy),
        ("episode", f"{max(v.episodes_done, 0)}/{v.episodes} done" + (  # (numbered as eval's)
            f", playing episode {v.ep}" if v.episodes_done < v.episodes else "")),
        ("tick", str(v.tick)), ("ticks/s (wall)", f"{v.ticks_per_s:.1f}"),
        ("clock", v.clock + (f"  t = {v.vtime:.1f} s" if v.clock == "virtual" else "")),
        ("elratio", f"{v.elratio:.3f}"),
        ("collisions", f"block {v.block_coll}  robot {v.robot_coll}"),
        ("links heard", str(v.heard_links)),
        ("msgs/s", f"{sum(r.msgs_out for r in v.robots.values()) / elapsed:.0f}"),
        ("bytes/s", f"{sum(r.bytes_out for r in v.robots.values()) / elapsed:.0f}"),
        ("timeouts", str(v.timeouts)), ("bad / late", f"{v.bad} / {v.late}"),
        ("robots alive", f"{sum(r.alive for r in v.robots.values())}/{v.n_robots}"),
        ("faults", "; ".join(v.faults) or "none"),
        ("radio", " ".join(f"{k} {v.radio.get(k, 0)}" for k in RADIO_COUNTS)),
        ("process faults", "; ".join(v.events) or "none"),
    ]
    for k, val in rows:
        if k == "radio" and compact:  # (the nonzero counts: three lines become one)
            val = " ".join(f"{n} {v.radio[n]}" for n in RADIO_COUNTS if v.radio.get(n)) or "-"
        if not compact or k in COMPACT_FIGURES:
            table.add_row(k, val)
    return table


def render_links(v: SwarmView, top: int = 8) -> Table:
    """The links the faults hurt most: delivered, dropped, late and queued messages."""
    table = Table(title="faulted links", expand=True, pad_edge=False)
    for col in ("link", "delivered", "dropped", "late", "queued"):
        table.add_column(col, justify="right")
    worst = sorted(v.links.items(), key=lambda kv: -(kv[1][1] + kv[1][2] + kv[1][3]))[:top]
    for link, (delivered, dropped, late, queued) in worst:
        table.add_row(link.replace("-", "→"), str(delivered), str(dropped), str(late), str(queued))
    return table


def render_attention(v: SwarmView) -> Table:
    """Per robot reporting attention: the member it attends to most and that weight, its weight
    on itself, how many it weighed (heard) and at which tick."""
    table = Table(title="attention (strongest)", expand=True, pad_edge=False)
    for col in ("robot", "→ member", "weight", "self", "heard", "tick"):
        table.add_column(col, justify="right")
    top = v.strongest()
    fmt = lambda x: f"{x:.2f}" if x >= 0.01 or x == 0 else f"{x:.1e}"  # noqa: E731
    for i in sorted(v.attention):
        t, w = v.attention[i]
        j, x = top.get(i, (None, 0.0))
        style = "bold" if v.attention_focus in (-1, i) else "dim"
        table.add_row(Text(str(i), style=style), "-" if j is None else str(j),
                      "-" if j is None else fmt(x), fmt(w[i]) if i < len(w) else "-",
                      str(sum(1 for y in w if y > 0)), str(t))
    return table


SPARK = "▁▂▃▄▅▆▇█"


def sparkline(values: list[float]) -> str:
    """A one-line curve of `values` (the learner's elratio per update)."""
    if not values:
        return "-"
    lo, hi = min(values), max(values)
    span, top = hi - lo or 1.0, len(SPARK) - 1
    return "".join(SPARK[min(int((x - lo) / span * top + 0.5), top)] for x in values)


def render_learner(v: SwarmView) -> Table:
    """The learner's figures: weights version, episodes gathered, its curve, rollout traffic."""
    rec = v.learner or {}
    table = Table.grid(padding=(0, 2))
    table.add_column(style="bold")
    table.add_column()
    last, curve = rec.get("last") or {}, [float(x) for x in rec.get("curve", [])]
    rows = [
        ("weights version", str(rec.get("version", "-"))),
        ("episodes gathered", f"{rec.get('episodes', 0)} (waiting {rec.get('ready', 0)}, "
                              f"joining {rec.get('pending', 0)})"),
        ("updates", str(rec.get("updates", 0))),
        ("elratio per update", sparkline(curve) + (f"  {curve[-1]:.3f}" if curve else "")),
        ("last loss", "-" if last.get("loss") is None else f"{last['loss']:.4f}"),
        ("rollout bytes/s", f"{rec.get('rollout_bytes_per_s', 0.0):.0f}"),
        ("older weights' episodes", f"used {rec.get('stale_used', 0)} (importance-weighted), "
                                    f"dropped {rec.get('stale_dropped', 0)} (too old)"),
        ("incomplete / bad", f"{rec.get('incomplete', 0)} / {rec.get('bad', 0)}"),
    ]
    acc = rec.get("accounting") or {}
    if acc:
        rows.append(("episodes received", f"{acc.get('received', 0)} = trained "
                     f"{acc.get('trained', 0)} + pending {acc.get('pending', 0)} + too old "
                     f"{acc.get('stale_dropped', 0)} + incomplete {acc.get('incomplete', 0)} + "
                     f"rejected {acc.get('rejected', 0)}"
                     + (f" + lost at a restart {acc['lost']}" if acc.get("lost") else "")))
    for k, val in rows:
        table.add_row(k, val)
    return table


SIDE_MIN = 30
"""Columns the figures and tables need beside the map; with fewer they go below it."""


class _Screen:
    """The map beside the side panels when the console leaves them SIDE_MIN columns, else
    above them (a map wider than the console used to leave the panels no width at all); the
    robot table keeps the columns its width holds. With `fit` (a live terminal, which crops
    what is taller than itself) the side panels shrink to the console's height: the figures
    that matter most, then fewer extra panels, then fewer robot rows (those in trouble kept);
    a map taller than the console goes below the figures rather than hide them."""

    def __init__(self, v: SwarmView, fit: bool = False) -> None:
        self.v, self.fit = v, fit

    def _side(self, width: int, level: int, rows: int | None = None) -> list[Any]:
        v = self.v
        side: list[Any] = [Panel(render_figures(v, compact=level > 0), title="swarm"),
                           render_robots(v, width, rows)]
        if v.learner is not None:
            side.insert(1, Panel(render_learner(v), title="learner"))
        if v.links and level < 3:
            side.append(render_links(v))
        if v.attention and v.attention_focus is not None and level < 2:
            side.append(render_attention(v))
        return side

    def _fitted(self, console: Console, options: ConsoleOptions, width: int,
                budget: int) -> list[Any]:
        """The richest side panels of `width` that fit in `budget` lines."""
        def lines(side: list[Any]) -> int:
            return len(console.render_lines(Group(*side), options.update(width=width,
                                                                         height=None)))
        for level in range(4):
            side = self._side(width, level)
            if not self.fit or lines(side) <= budget:
                return side
        rows = len(self.v.robots) - (lines(side) - budget) - 1  # (1: the caption)
        side = self._side(width, 3, rows)
        while rows > 0 and lines(side) > budget:  # (a caption that wraps)
            rows -= 1
            side = self._side(width, 3, rows)
        return side

    def __rich_console__(self, console: Console, options: ConsoleOptions) -> RenderResult:
        v = self.v
        grid = Panel(render_grid(v), title=f"map {v.height}x{v.width}", expand=False)
        room = options.max_width - Measurement.get(console, options, grid).maximum - 1
        height = options.max_height
        if room >= SIDE_MIN:
            screen = Table.grid(padding=(0, 1))
            screen.add_column(no_wrap=True)
            screen.add_column(ratio=1)
            screen.add_row(grid, Group(*self._fitted(console, options, room, height)))
            yield screen
            return
        grid_lines = v.height + 2
        if self.fit and grid_lines >= height:  # the map alone fills the terminal: figures first
            yield Group(*self._fitted(console, options, options.max_width, height), grid)
            return
        yield Group(grid, *self._fitted(console, options, options.max_width, height - grid_lines))


def render(v: SwarmView, fit: bool = False) -> _Screen:
    """The whole screen: the map beside (or above) the figures, the robot table and the
    faulted links; it takes the height of its content (not a Layout), or with `fit` at most
    the console's height where it can."""
    return _Screen(v, fit)
