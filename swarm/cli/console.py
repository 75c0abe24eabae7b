"""Pure rich renderers: result data in, a `rich.table.Table` out (no printing, no I/O).

The CLI prints what these return; tests render them into a capture console.
"""

from __future__ import annotations

import io
from collections.abc import Mapping, Sequence
from typing import Any

from rich.console import Console
from rich.measure import Measurement
from rich.table import Table
from rich.text import Text

from swarm.common.report import counted, paired_cell


def _ok(flag: bool | None) -> Text:
    if flag is None:
        return Text("-", style="dim")
    return Text("yes", style="green") if flag else Text("NO", style="bold red")


def _pm(mean: float, std: float, fmt: str = ".3f") -> str:
    return f"{mean:{fmt}} ± {std:{fmt}}"


def _num(x: float | None, fmt: str) -> str:
    return "-" if x is None else f"{x:{fmt}}"  # (None: a run stopped before any episode ended)


def eval_table(summaries: Sequence[Mapping[str, Any]], title: str = "Evaluation",
               width: int | None = None) -> Table:
    """One row per policy from `EvalResult.summary` dicts; * marks a reference planner that is
    not decentralized (oracle, central); with several policies, each one's elratio minus the
    first's, paired over the same episodes. The table degrades to fit `width` (the console's)
    so that every figure stays whole (an 80-column terminal cut them to `0.…`): means without
    their standard deviations (in `--json`) and no rules; then the policies as columns and the
    figures as rows; then one block of figures per policy, stacked (~30 columns)."""
    wide = _eval_table(summaries, title, narrow=False)
    if width is None:
        return wide
    for layout in (lambda: wide, lambda: _eval_table(summaries, title, narrow=True),
                   lambda: _eval_table(summaries, title, narrow=True, turned=True)):
        table = layout()
        if _natural_width(table) <= width:
            return table
    return _eval_table(summaries, title, narrow=True, stacked=True)


def _natural_width(table: Table) -> int:
    """The columns a table takes when nothing is cut."""
    probe = Console(width=10_000, file=io.StringIO())
    return Measurement.get(probe, probe.options, table).maximum


def _eval_table(summaries: Sequence[Mapping[str, Any]], title: str, narrow: bool,
                turned: bool = False, stacked: bool = False) -> Table:
    """The results as rows per policy; `turned`: a column per policy instead; `stacked`: one
    block per policy (its name, then a row per figure)."""
    vs = next((s["elratio_paired"]["vs"] for s in summaries if "elratio_paired" in s), None)
    sd = "" if narrow else " ± sd"
    heads = [f"elratio{sd}", f"reward{sd}", "coll.", "block" if narrow else "block coll.",
             "success", "plan ms", *(["Δ elratio ± se"] if vs else [])]

    def pm(mean: float | None, std: float | None, fmt: str = ".3f") -> str:
        return _num(mean, fmt) if narrow or mean is None else _pm(mean, std or 0.0, fmt)

    rows: list[tuple[str, list[str]]] = []  # (policy, its figures under `heads`)
    for s in summaries:
        pair = s.get("elratio_paired")
        success = s.get("success_rate")
        rows.append((str(s["policy"]) + ("" if s.get("decentralized", True) else " *"), [
            pm(s["elratio_mean"], s["elratio_std"]),
            pm(s["reward_mean"], s.get("reward_std", 0.0), ".1f"),
            _num(s["collisions_mean"], ".2f"),
            _num(s["block_collisions_mean"], ".2f"),
            "-" if success is None else f"{100 * success:.1f}%",
            _num(s["planning_ms_per_decision"], ".3f"),
            *([(paired_cell(pair["mean"], pair["se"]).replace(" ± ", "±") if narrow else
                paired_cell(pair["mean"], pair["se"])) if pair else "-"] if vs else [])]))
    table = Table(title=title, title_justify="left", **(  # (no vertical rules, no edges)
        {"box": None, "pad_edge": False, "collapse_padding": True} if narrow else {}))
    if stacked:
        table.add_column("policy", no_wrap=True)
        table.add_column("", justify="right", no_wrap=True)
        for k, (policy, cells) in enumerate(rows):
            table.add_row(Text(policy, style="bold"), "")
            for head, cell in zip(heads, cells, strict=True):
                table.add_row(f"  {head}", cell, end_section=k < len(rows) - 1 and
                              head == heads[-1])
    elif turned:
        table.add_column("", no_wrap=True)
        for policy, _ in rows:
            table.add_column(policy, justify="right", style=None, header_style="bold",
                             no_wrap=True)
        for j, head in enumerate(heads):
            table.add_row(head, *(cells[j] for _, cells in rows))
    else:
        table.add_column("policy", style="bold", no_wrap=True)  # (not `coordinated-fron…`)
        for head in heads:
            table.add_column(head, justify="right", no_wrap=True)
        for policy, cells in rows:
            table.add_row(policy, *cells)
    notes = ([f"Δ: elratio minus {vs}'s on the same episodes (paired; se of the mean)"]
             if vs else [])
    notes.append("reward: the episode's return per robot (SPEC rewards summed over the steps, "
                 "averaged over the team)")
    notes.append("plan ms: per team decision (eval: the batched act amortized over its "
                 "episodes; run: every robot's own decision, summed)")
    if any(not s.get("decentralized", True) for s in summaries):
        notes.append("* a reference planner, not decentralized (see README, Reference planners)")
    if narrow:
        notes.append("means only, to fit the terminal: the standard deviations are in --json")
    table.caption = "\n".join(notes)
    table.caption_justify = "left"
    return table


def env_bench_table(result: Mapping[str, Any]) -> Table:
    """Rows of `bench_env`: agent-steps/s per batch size and whether the project bar is met."""
    bar_b = result.get("bar", {}).get("batch")
    bar = result.get("bar", {}).get("agent_steps_per_s")
    table = Table(title=f"World step + view, N={result['robots']}, T={result['horizon']} "
                        f"(median of {result['repeats']} repeats)", title_justify="left")
    table.add_column("batch B", justify="right")
    table.add_column("agent-steps/s", justify="right", style="bold")
    table.add_column("min .. max", justify="right")
    table.add_column("per CPU-s", justify="right")
    table.add_column("ms / step", justify="right")
    table.add_column("reset ms / episode", justify="right")
    table.add_column("bar", justify="right")
    for r in result["rows"]:
        meets = (r["agent_steps_per_s"] >= bar) if (bar and r["batch"] == bar_b) else None
        table.add_row(
            str(r["batch"]), f"{r['agent_steps_per_s']:,.0f}",
            f"{r['min']:,.0f} .. {r['max']:,.0f}", f"{r['agent_steps_per_cpu_s']:,.0f}",
            f"{r['step_ms']:.3f}",
            f"{r['reset_ms_per_episode']:.2f}",
            _ok(meets) if meets is None else Text.assemble(_ok(meets), f" (≥{bar:,.0f})"),
        )
    return table


def policy_bench_table(result: Mapping[str, Any]) -> Table:
    """Rows of `bench_policy`: planning ms per team decision of N robots."""
    who = "one robot as a robot process makes it" if result.get("one_robot") else "G=1"
    table = Table(title=f"Planning time per decision, {result['robots']} robots, {who} "
                        f"({result['decisions']} decisions each)", title_justify="left")
    table.add_column("policy", style="bold")
    for col in ("median ms", "p90 ms", "mean ± std ms", "bar ms", "meets bar"):
        table.add_column(col, justify="right")
    for r in result["rows"]:
        table.add_row(
            r["policy"], f"{r['median_ms']:.3f}", f"{r['p90_ms']:.3f}",
            _pm(r["mean_ms"], r["std_ms"]), "-" if r["bar_ms"] is None else f"{r['bar_ms']:g}",
            _ok(r["meets_bar"]),
        )
    return table


def table1_table(rows: Sequence[Mapping[str, Any]]) -> Table:
    """Table 1: our planning time next to the paper's."""
    robots = sorted({r["robots"] for r in rows if "robots" in r}) or [10]
    table = Table(title="Table 1: planning time per decision (ms), "
                        f"{'/'.join(map(str, robots))} robots", title_justify="left")
    table.add_column("policy", style="bold")
    table.add_column("ours mean ± std", justify="right")
    table.add_column("ours median", justify="right")
    table.add_column("ours p90", justify="right")
    table.add_column("paper", justify="right")
    for r in rows:
        paper = ("-" if r["paper_mean_ms"] is None
                 else _pm(r["paper_mean_ms"], r["paper_std_ms"], "g"))
        table.add_row(r["policy"], _pm(r["mean_ms"], r["std_ms"]), f"{r['median_ms']:.3f}",
                      f"{r['p90_ms']:.3f}", paper)
    return table


def table2_table(rows: Sequence[Mapping[str, Any]]) -> Table:
    """Table 2: every policy on the same held-out episodes, next to the paper's figures."""
    n, first = (rows[0]["episodes"], rows[0]["policy"]) if rows else (0, "")
    gap = any(r.get("gap_closed") is not None for r in rows)  # (random and oracle both played)
    starred = not all(r.get("decentralized", True) for r in rows)
    said = ["* not decentralized"] if starred else []
    said += ["gap: share of the oracle-to-random elratio gap closed"] if gap else []
    table = Table(title=f"Table 2: dynamic map, {counted(n, 'held-out episode')} per policy",
                  title_justify="left", caption_justify="left",
                  caption="; ".join(said) + ("; " if said else "") + "table2.md says more")
    table.add_column("policy", style="bold")
    for col in ("reward / robot", "collisions (block)", "elratio", "success", "paper",
                f"{first} - this (paired)", *(["gap"] if gap else [])):
        table.add_column(col, justify="right")
    for r in rows:
        paper = ("-" if r["paper_reward"] is None else
                 f"{r['paper_reward']:g} / {r['paper_collisions']:g} / "
                 f"{r['paper_elratio_pct']:g}%")
        lead = "-" if r is rows[0] else paired_cell(r["first_minus_elratio"],
                                                    r["first_minus_elratio_se"])
        table.add_row(r["policy"] + ("" if r.get("decentralized", True) else " *"),
                      f"{r['reward_mean']:.1f}",
                      f"{r['collisions_mean']:.2f} ({r['block_collisions_mean']:.2f})",
                      _pm(r["elratio_mean"], r["elratio_std"]),
                      f"{100 * r['success_rate']:.1f}%", paper, lead,
                      *(["-" if r["gap_closed"] is None else f"{100 * r['gap_closed']:.1f}%"]
                        if gap else []))
    return table


def curves_table(rows: Sequence[Mapping[str, Any]]) -> Table:
    """Fig. 8: the last smoothed point of each policy's training curve."""
    last: dict[str, Mapping[str, Any]] = {}
    for r in rows:
        last[r["policy"]] = r
    table = Table(title="Fig. 8: end of the training curves (smoothed)", title_justify="left")
    table.add_column("policy", style="bold")
    for col in ("episodes", "elratio", "reward / robot"):
        table.add_column(col, justify="right")
    for name, r in last.items():
        table.add_row(name, f"{r['episodes']:,}", f"{r['elratio']:.3f}", f"{r['reward']:.1f}")
    return table


def sweep_table(title: str, x_name: str, rows: Sequence[Mapping[str, Any]]) -> Table:
    """A sweep (Fig. 4/5): one row per x value, one column per policy, elratio mean ± std."""
    policies = list(dict.fromkeys(r["policy"] for r in rows))
    xs = list(dict.fromkeys(r[x_name] for r in rows))
    cell = {(r["policy"], r[x_name]): r for r in rows}
    table = Table(title=title, title_justify="left")
    table.add_column(x_name, justify="right", style="bold")
    for p in policies:
        table.add_column(p, justify="right")
    for x in xs:
        vals = [cell.get((p, x)) for p in policies]
        table.add_row(str(x), *("-" if v is None else _pm(v["elratio_mean"], v["elratio_std"])
                                for v in vals))
    return table


def files_table(paths: Mapping[str, Sequence[str]]) -> Table:
    """Which files each reproduced item wrote."""
    table = Table(title="Written", title_justify="left")
    table.add_column("item", style="bold")
    table.add_column("files")
    for item, files in paths.items():
        table.add_row(item, "\n".join(files))
    return table


def swarm_bench_table(result: Mapping[str, Any]) -> Any:
    """Rows of `bench_swarm` (one real swarm run per policy and team size) as two tables: the
    figures, then where a tick goes (wall ms in the world by phase, CPU ms by process kind)."""
    from rich.console import Group

    def f(x: Any, fmt: str = ".1f") -> str:
        return "-" if x is None else format(x, fmt)

    main = Table(title=f"Swarm benchmark ({result['episodes']} episodes per run)",
                 title_justify="left")
    main.add_column("policy", style="bold")
    for col in ("robots", "map", "ticks/s", "1st tick s", "RSS/PSS MB robot",
                "RSS/PSS MB world", "elratio", "lost"):
        main.add_column(col, justify="right")
    ticks = Table(title="Where a tick goes (ms per tick: wall time in the world by phase; CPU by "
                        "process kind)", title_justify="left")
    ticks.add_column("policy", style="bold")
    for col in ("robots", "obs", "collect", "radio", "decide", "step", "CPU world",
                "CPU robots", "chain head", "per hop"):
        ticks.add_column(col, justify="right")
    for r in result["rows"]:
        ph, cpu = r.get("tick_ms") or {}, r.get("cpu_ms_per_tick") or {}
        main.add_row(r["policy"], str(r["robots"]), r.get("size", "-"), f(r["ticks_per_s"]),
                     f(r["startup_s"], ".2f"),
                     f"{f(r['rss_mb_per_robot'], '.0f')}/{f(r.get('pss_mb_per_robot'), '.0f')}",
                     f"{f(r['rss_mb_world'], '.0f')}/{f(r.get('pss_mb_world'), '.0f')}",
                     f(r["elratio_mean"], ".3f"),
                     str(r["timeouts"] + (r.get("robots_lost") or 0)))
        ticks.add_row(r["policy"], str(r["robots"]),
                      *(f(ph.get(k)) for k in ("obs", "collect", "radio", "decide", "step")),
                      f(cpu.get("world")), f(cpu.get("robots")), *chain_figures(r))
    if any(not r.get("cpu_ms_per_tick") for r in result["rows"]):
        ticks.caption = ("CPU -: the run was too short for two samples after its first tick "
                         "(the sampler's); ~20 episodes give the CPU figures")
        ticks.caption_justify = "left"
    if result.get("repeats", 1) < 2:
        return Group(main, ticks)
    first = result["rows"][0]["policy"]
    med = Table(title=f"Medians over {result['repeats']} interleaved rounds",
                title_justify="left")
    med.add_column("policy", style="bold")
    ref = f"x {first} median" + (" (+secure: x itself plain)" if result.get("secure") else "")
    for col in ("robots", "ticks/s median", "ticks/s per round", ref, "per round"):
        med.add_column(col, justify="right")
    for m in result["summary"]:
        med.add_row(m["policy"], str(m["robots"]), f(m["ticks_per_s_median"]),
                    " ".join(f(x) for x in m["ticks_per_s"]), f(m["vs_first_median"], ".3f"),
                    " ".join(f(x, ".2f") for x in m["vs_first"]))
    return Group(main, ticks, med)


def chain_figures(row: Mapping[str, Any]) -> tuple[str, str]:
    """(chain head, per hop) in ms of a chained policy's run: when the first hidden-state
    messages reached the world after the bundles went out, and the mean step per chain position
    from there to the deepest position ('-' for policies without a chain)."""
    depth = row.get("chain_ms_by_depth") or []
    if not depth:
        return "-", "-"
    hop = (depth[-1] - depth[0]) / (len(depth) - 1) if len(depth) > 1 else None
    return format(depth[0], ".1f"), "-" if hop is None else format(hop, ".2f")


def kv_table(title: str, record: Mapping[str, Any]) -> Table:
    """A record as a two-column table (numbers to 3 decimals)."""
    table = Table(title=title, title_justify="left")
    table.add_column("figure", style="bold")
    table.add_column("value", justify="right")
    for k, v in record.items():
        table.add_row(k, f"{v:.3f}" if isinstance(v, float) else str(v))
    return table


def rollout_bench_table(result: Mapping[str, Any]) -> Table:
    """Rows of `bench_rollout`: episodes/s the learner gathered per worker count."""
    table = Table(title="Rollout workers -> learner (median episodes/s)", title_justify="left")
    for col in ("workers", "episodes/s", "speedup", "rollout kB/s", "windows"):
        table.add_column(col, justify="right")
    for r in result["rows"]:
        table.add_row(str(r["workers"]), f"{r['episodes_per_s']:.1f}", f"{r['speedup']:.2f}x",
                      f"{r['rollout_bytes_per_s'] / 1e3:.0f}",
                      " ".join(f"{x:.1f}" for x in r["episodes_per_s_windows"]))
    return table
