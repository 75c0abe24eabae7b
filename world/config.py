"""Typed world configuration (SPEC section 2) and the TOML/CLI loading shared by every entry
point."""

from __future__ import annotations

import dataclasses
import math
import tomllib
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any, TypeVar

T = TypeVar("T")


class ConfigError(ValueError):
    """A bad configuration value or key; its message is one line meant for the user."""


MAX_SIDE = 1000  # the largest grid side (`--size` and every config)
MAX_HORIZON = 100_000  # the longest mission (the paper's: 30 steps)
SEED_MAX = 2**31 - 1  # every seed keys numpy's SeedSequence and the msgpack int32 fields
MAX_COUNT = 10**9  # the largest count a config takes (episodes, collisions): bounded, not 10^400
MAX_COMM_RANGE = 10**6  # the largest finite comm range (squared, floored to an int in the radio)


def check_seed(seed: Any, name: str = "seed") -> None:
    """A seed is an int (or numpy integer) in [0, SEED_MAX]; anything else is a one-line
    ConfigError that says which rule it breaks (1.5, "3" and True are no integers)."""
    integer = isinstance(seed, int) or (getattr(seed, "ndim", None) == 0
                                        and seed.dtype.kind in "iu")
    if isinstance(seed, bool) or not integer:
        raise ConfigError(f"{name} must be an integer in [0, {SEED_MAX}], got {seed!r}")
    if not 0 <= seed <= SEED_MAX:
        raise ConfigError(f"{name} must lie in [0, {SEED_MAX}], got {seed!r}")


def check_count(value: Any, name: str, hi: int = MAX_COUNT, lo: int = 1) -> None:
    """A count (episodes, a batch) is an int in [lo, hi]; anything else, 10^400 or 2.5 or
    True, is a one-line ConfigError that names the bound, caught before anything runs."""
    if isinstance(value, bool) or not isinstance(value, int) or not lo <= value <= hi:
        raise ConfigError(f"{name} must be an integer in [{lo}, {hi}], got {value!r}")


@dataclass(frozen=True)
class WorldConfig:
    """Every size and weight of the dynamic exploration world; defaults are the paper's values."""

    height: int = 20
    """Grid rows H."""
    width: int = 20
    """Grid columns W."""
    n_static: int = 81
    """Static blocks placed by the maze generator."""
    n_dynamic: int = 70
    """Dynamic blocks that appear during the mission (0 or `dynamic=False` gives a static map)."""
    dynamic: bool = True
    """Whether dynamic blocks are activated at all."""
    add_every: int = 3
    """Steps between dynamic-block batches (`m`); batch size is
    ceil(n_dynamic / floor(0.9 T / m))."""
    n_robots: int = 10
    """Robots N."""
    spawn: str = "random"
    """Start cells: `random` (distinct random free cells) or `corner` (free cells nearest the
    top-left)."""
    vision: int = 5
    """Side v of the square v x v patch each robot sees (odd)."""
    comm_range: float = 10.0
    """Euclidean communication range in cells; `inf` lets every robot hear every other."""
    horizon: int = 30
    """Mission length T in steps; every episode runs exactly T steps."""
    explore_mode: str = "visit"
    """`visit`: a cell is explored once a robot stood on it; `sense`: every cell seen is
    explored."""
    r_back: float = -10.0
    """Reward for standing on an already explored cell (visit) or revealing nothing new (sense)."""
    r_coll: float = -10.0
    """Reward per collision (block or robot) in a step."""
    r_succ: float = 40.0
    """Reward to every robot on the last step when the mission succeeded."""
    r_fail: float = -5.0
    """Reward to every robot on the last step when the mission failed."""
    success_elratio: float = 0.9
    """Success needs elratio at the last step at least this."""
    success_max_block_collisions: int = 0
    """Success needs the team's block collisions over the episode at most this."""
    recent_len: int = 8
    """How many recent positions a trajectory message carries besides the visited bitmap."""

    def __post_init__(self) -> None:
        def bad(msg: str) -> None:
            raise ConfigError(f"world config: {msg}")

        for f in fields(self):  # built in code too, not only by from_dict: types checked here
            v, kind = getattr(self, f.name), f.type if isinstance(f.type, str) else f.type.__name__
            if kind in ("int", "float") and hasattr(v, "dtype") and v.dtype.kind in "iuf" \
                    and v.ndim == 0:  # a numpy scalar: its Python value (JSON, msgpack)
                v = int(v) if v.dtype.kind in "iu" else float(v)
                object.__setattr__(self, f.name, v)
            ok = {"int": isinstance(v, int), "float": isinstance(v, (int, float)),
                  "bool": isinstance(v, bool), "str": isinstance(v, str)}[kind]
            if not ok or (kind in ("int", "float") and isinstance(v, bool)):
                bad(f"{f.name} must be {kind}, got {v!r}")
        if not (3 <= self.height <= MAX_SIDE and 3 <= self.width <= MAX_SIDE):
            bad(f"grid must be between 3 x 3 and {MAX_SIDE} x {MAX_SIDE}, got {self.height} x "
                f"{self.width}")
        for name in ("r_back", "r_coll", "r_succ", "r_fail"):  # (nan made every reward nan)
            if not abs(getattr(self, name)) <= 1e6:
                bad(f"{name} must be a finite number in [-1e6, 1e6], got {getattr(self, name)}")
        if not 0.0 <= self.success_elratio <= 1.0:
            bad(f"success_elratio must lie in [0, 1], got {self.success_elratio}")
        if self.vision < 1 or self.vision % 2 == 0 or self.vision > 2 * MAX_SIDE + 1:
            bad(f"vision must be an odd number in [1, {2 * MAX_SIDE + 1}], got {self.vision}")
        if self.n_robots < 1:
            bad(f"n_robots must be >= 1, got {self.n_robots}")
        if not 1 <= self.horizon <= MAX_HORIZON:  # (10^12 tried to allocate 7 TiB)
            bad(f"horizon must lie in [1, {MAX_HORIZON}], got {self.horizon}")
        if not 1 <= self.add_every <= MAX_HORIZON:  # (a 400-digit one overflowed a float)
            bad(f"add_every must lie in [1, {MAX_HORIZON}], got {self.add_every}")
        if not (0 <= self.comm_range <= MAX_COMM_RANGE or self.comm_range == math.inf):
            bad(f"comm_range must lie in [0, {MAX_COMM_RANGE}] or be inf (unlimited), got "
                f"{self.comm_range}")  # (1e300 squared overflowed to inf deep in the radio)
        if self.spawn not in ("random", "corner"):
            bad(f"spawn must be 'random' or 'corner', got {self.spawn!r}")
        if self.explore_mode not in ("visit", "sense"):
            bad(f"explore_mode must be 'visit' or 'sense', got {self.explore_mode!r}")
        if self.n_static < 0 or self.n_dynamic < 0:
            bad("block counts must be >= 0")
        cells = self.height * self.width
        need = self.n_static + self.n_robots + (self.n_dynamic if self.dynamic else 0)
        if need > cells:
            bad(f"{need} blocks and robots do not fit on {cells} cells")
        if self.dynamic and self.n_dynamic > 0 and \
                math.floor(0.9 * self.horizon / self.add_every) < 1:
            bad(f"add_every={self.add_every} leaves no batch before 90% of horizon={self.horizon}")
        if not 1 <= self.recent_len <= 1000:
            bad(f"recent_len must lie in [1, 1000], got {self.recent_len}")
        if not 0 <= self.success_max_block_collisions <= MAX_COUNT:
            bad(f"success_max_block_collisions must lie in [0, {MAX_COUNT}], got "
                f"{self.success_max_block_collisions}")

    @property
    def cells(self) -> int:
        """Grid cells H * W (elratio's denominator, a bitmap's length)."""
        return self.height * self.width

    @property
    def pad(self) -> int:
        """Border of wall cells around the grid, wide enough for every vision patch."""
        return max(1, self.vision // 2)

    @property
    def n_active_dynamic(self) -> int:
        return self.n_dynamic if self.dynamic else 0

    @property
    def batch_size(self) -> int:
        """Dynamic blocks per batch, n = ceil(n_dynamic / floor(0.9 T / m))."""
        if self.n_active_dynamic == 0:
            return 0
        return math.ceil(self.n_dynamic / math.floor(0.9 * self.horizon / self.add_every))


PAPER_CELLS = 20 * 20  # the paper's map; block counts scale from it by area


def scaled_blocks(height: int, width: int) -> dict[str, int]:
    """Static and dynamic block counts of an H x W map at the paper's densities (81 and 70 on
    20 x 20), rounded: what `--size` gives unless the counts are set too."""
    area = height * width / PAPER_CELLS
    return {"n_static": round(WorldConfig.n_static * area),
            "n_dynamic": round(WorldConfig.n_dynamic * area)}


def with_scaled_blocks(table: dict[str, Any], where: str = "[world]") -> dict[str, Any]:
    """`table` with the block counts of its map size at the paper's densities where the size is
    given and the counts are not (what `--size` does; an experiment file's `[world]` too)."""
    h, w = table.get("height"), table.get("width")
    if h is None and w is None:
        return table
    size = [WorldConfig.height if h is None else h, WorldConfig.width if w is None else w]
    if not all(isinstance(v, int) and not isinstance(v, bool) for v in size):
        raise ConfigError(f"{where}: height and width must be int, got {h!r} and {w!r}")
    return {**scaled_blocks(size[0], size[1]), **table}


def parse_size(text: str) -> tuple[int, int]:
    """`HxW` (e.g. `40x40`) -> (H, W); a one-line ConfigError otherwise."""
    h, sep, w = str(text).lower().partition("x")
    try:
        if not sep:
            raise ValueError
        size = int(h), int(w)
    except ValueError:
        raise ConfigError(f"size must be HxW (e.g. 40x40), got {text!r}") from None
    if min(size) < 3 or max(size) > MAX_SIDE:
        raise ConfigError(f"size must be between 3x3 and {MAX_SIDE}x{MAX_SIDE}, got {text!r}")
    return size


def toml_bools(cls: type, table: dict[str, Any], where: str) -> None:
    """A switch of dataclass `cls` in a TOML `table` must be a TOML boolean: `dynamic = 1` or
    `"yes"` is one line, not read as a setting (from_dict also takes "true"/1 for flag text)."""
    for f in fields(cls):
        name = f.type if isinstance(f.type, str) else getattr(f.type, "__name__", "")
        if name == "bool" and f.name in table and not isinstance(table[f.name], bool):
            raise ConfigError(f"{where} {f.name} must be true or false, got {table[f.name]!r}")


def from_dict(cls: type[T], data: dict[str, Any], where: str = "config") -> T:
    """Build dataclass `cls` from `data`, rejecting unknown keys and coercing simple types."""
    known = {f.name: f for f in fields(cls)}  # type: ignore[arg-type]
    unknown = sorted(set(data) - set(known))
    if unknown:
        raise ConfigError(f"{where}: unknown key(s) {', '.join(unknown)}; "
                          f"known: {', '.join(known)}")
    kwargs: dict[str, Any] = {}
    for key, value in data.items():
        ftype = known[key].type
        ftype = ftype if isinstance(ftype, str) else getattr(ftype, "__name__", str(ftype))
        try:
            if ftype == "int":  # (a float, even 3.0 or 1e300, is refused as the flags refuse it)
                if isinstance(value, (bool, float)) or \
                        getattr(getattr(value, "dtype", None), "kind", "") == "f":
                    raise ValueError
                kwargs[key] = int(value)
            elif ftype == "float":  # (true is no number: float(True) would be 1.0)
                if isinstance(value, bool):
                    raise ValueError
                kwargs[key] = float(value)
            elif ftype == "bool":
                if isinstance(value, str):
                    if value.lower() not in ("true", "false", "1", "0"):
                        raise ValueError
                    value = value.lower() in ("true", "1")
                elif not isinstance(value, bool) and value not in (0, 1):
                    raise ValueError  # 3 or [] is no switch setting, not a truthy one
                kwargs[key] = bool(value)
            elif ftype in ("str", "str | None"):  # (a number for a path or a name: refused)
                if not isinstance(value, str) and not (value is None and "None" in ftype):
                    raise TypeError
                kwargs[key] = value
            elif ftype.startswith("tuple["):  # a list, or "a,b" text; the class checks items
                if not isinstance(value, (list, tuple, str)):
                    raise TypeError
                kwargs[key] = value
            else:
                kwargs[key] = value
        except (TypeError, ValueError):
            raise ConfigError(f"{where}: {key} must be {ftype}, got {value!r}") from None
    return cls(**kwargs)


def replace(cfg: T, **changes: Any) -> T:
    """`dataclasses.replace` that ignores `None` values (unset CLI flags)."""
    changes = {k: v for k, v in changes.items() if v is not None}
    return dataclasses.replace(cfg, **changes)  # type: ignore[type-var]


def load_toml(path: str | Path) -> dict[str, Any]:
    """Read a TOML experiment file; a missing or malformed file is a one-line ConfigError. A
    UTF-8 byte-order mark (some Windows editors write one) is read past, not a TOML error."""
    try:
        with open(path, "rb") as fh:
            data = fh.read()
        bom = 3 if data.startswith(b"\xef\xbb\xbf") else 0
        return tomllib.loads(data[bom:].decode("utf-8"))
    except FileNotFoundError:
        raise ConfigError(f"config file not found: {path}") from None
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"config file {path}: {exc}") from None
    except UnicodeDecodeError as exc:
        where = exc.start + bom
        raise ConfigError(f"config file {path} is not UTF-8 text (byte {where})") from None
    except IsADirectoryError:
        raise ConfigError(f"config file {path} is a directory") from None
    except OSError as exc:
        raise ConfigError(f"config file {path}: {exc.strerror or exc}") from None


def to_dict(cfg: Any) -> dict[str, Any]:
    """Plain dict of a config dataclass (JSON-safe: inf becomes the string 'inf')."""
    out = dataclasses.asdict(cfg)
    return {k: ("inf" if isinstance(v, float) and math.isinf(v) else v) for k, v in out.items()}
