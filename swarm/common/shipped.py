"""Where the shipped data lives: the trained networks (`checkpoints/`) and the deployment
files (`deploy/`).

In a source tree (a checkout, an editable install) they are the tree's own directories. A
regular install has no tree: the wheel carries them as data files into
`PREFIX/share/commattn-swarm/` (pyproject.toml), found here through the installed
distribution's file list.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from importlib.metadata import Distribution

DIST = "commattn-swarm"
SHARE = Path("share") / DIST  # below the install prefix
ROOT = Path(__file__).resolve().parents[2]  # the source tree (site-packages once installed)


def _own_distribution() -> Distribution | None:
    """The installed distribution this very module came from (another install of the project
    earlier on sys.path, an editable one say, holds other data or none)."""
    from importlib.metadata import distributions  # (~50 ms: only where there is no tree)

    me = Path(__file__).resolve()
    for dist in distributions(name=DIST):
        if Path(str(dist.locate_file(Path(*me.parts[-3:])))).resolve() == me:
            return dist
    return None


def installed_data() -> tuple[Path | None, Path]:
    """PREFIX/share/commattn-swarm of the installed distribution when it holds the data (else
    None), and where it was looked for (the place that exists, if one does). The wheel's RECORD
    names it relative to site-packages, right for a venv, user or system install; `pip install
    --target T` puts it in T/share but leaves those paths relative to a build directory that is
    gone, so T/share is tried too."""
    dist = _own_distribution()
    if dist is None:
        return None, Path("PREFIX") / SHARE
    places = [Path(str(dist.locate_file(SHARE))).resolve()]
    for f in dist.files or ():
        at = next((i for i in range(len(f.parts) - 1) if f.parts[i:i + 2] == SHARE.parts), None)
        if at is not None:
            places.insert(0, Path(str(dist.locate_file(Path(*f.parts[:at + 2])))).resolve())
            break
    found = next((p for p in places if (p / "checkpoints").is_dir()), None)
    return found, next((p for p in places if p.is_dir()), places[0])


def _find() -> tuple[Path, str]:
    """The directory holding checkpoints/ and deploy/ (the source tree's when it has them, else
    the installed data, else the source tree's, where they are missing), and where a shipped
    checkpoint is looked for, as an error names it."""
    if (ROOT / "checkpoints").is_dir():
        return ROOT, str(ROOT / "checkpoints")
    found, tried = installed_data()
    if found is not None:
        return found, str(found / "checkpoints")
    return ROOT, (f"{ROOT / 'checkpoints'} (a source tree) nor in {tried / 'checkpoints'} "
                  "(an installed package)")


DATA, SEARCHED = _find()
SHIPPED = DATA / "checkpoints"
