"""The project as a regular (not editable) install: the wheel carries the shipped networks and
the deployment files, and an installed `swarm` finds them from any directory."""

from __future__ import annotations

import importlib.util
import json
import os
import shutil
import site
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest
from conftest import ROOT

SOURCES = ("pyproject.toml", "README.md", "LICENSE", "world", "policies", "swarm", "checkpoints",
           "deploy")


def _wheel(out: Path, tmp: Path) -> Path:
    """Build the project's wheel into `out` from a copy of the source (the build leaves build/
    and egg-info where it runs); offline, with this venv's setuptools when it has one."""
    src = tmp / "src"
    src.mkdir()
    for name in SOURCES:
        if (ROOT / name).is_dir():
            shutil.copytree(ROOT / name, src / name, ignore=shutil.ignore_patterns("__pycache__"))
        else:
            shutil.copy2(ROOT / name, src / name)
    isolation = [] if importlib.util.find_spec("setuptools") is None else ["--no-build-isolation"]
    r = subprocess.run([sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", *isolation,
                        "-w", str(out), str(src)], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    return next(out.glob("commattn_swarm-*.whl"))


@pytest.mark.procs
def test_an_installed_package_runs_on_its_shipped_data(tmp_path: Path) -> None:
    """UA pass: the wheel held only the Python packages, and the shipped checkpoint was looked
    for in site-packages/checkpoints: `swarm eval --policy commattn` failed outside the repo.
    Installed with `pip install --target T` and run from elsewhere, it runs on the shipped
    checkpoint; without the data, one line names both places it looked. The wheel names its
    license in the SPDX form, with the LICENSE file."""
    wheel = _wheel(tmp_path / "dist", tmp_path)
    with zipfile.ZipFile(wheel) as z:  # the SPDX license form (the TOML table is deprecated)
        meta = z.read(next(n for n in z.namelist() if n.endswith(".dist-info/METADATA")))
        assert any(n.endswith(".dist-info/licenses/LICENSE") for n in z.namelist())
    assert b"\nLicense-Expression: MIT\n" in meta
    target = tmp_path / "site"
    r = subprocess.run([sys.executable, "-m", "pip", "install", "-q", "--no-deps", "--target",
                        str(target), str(wheel)], capture_output=True, text=True, timeout=300)
    assert r.returncode == 0, r.stderr
    data = target / "share" / "commattn-swarm"
    assert (data / "checkpoints" / "vision").is_dir() and (data / "deploy" / "experiments").is_dir()

    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    # -S: not this venv's site hooks (its editable install of the source tree); its packages
    # (the dependencies) come after the installed copy
    path = os.pathsep.join([str(target), *site.getsitepackages()])

    def swarm_installed(*args: str) -> subprocess.CompletedProcess[str]:
        return subprocess.run([sys.executable, "-S", "-m", "swarm.cli", *args], cwd=elsewhere,
                              capture_output=True, text=True, timeout=300,
                              env={**os.environ, "PYTHONPATH": path})

    out = elsewhere / "eval.json"
    r = swarm_installed("eval", "--policy", "commattn", "--episodes", "1", "--json", str(out))
    assert r.returncode == 0, r.stderr
    ckpt = json.loads(out.read_text())["checkpoint"]
    assert (target / ckpt).resolve() == data / "checkpoints" / "commattn.pt", ckpt
    r = swarm_installed("--version")
    assert r.returncode == 0 and str(data) in r.stdout, r.stdout + r.stderr

    shutil.rmtree(data / "checkpoints")
    r = swarm_installed("eval", "--policy", "commattn", "--episodes", "1")
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert str(target / "checkpoints") in r.stderr and str(data / "checkpoints") in r.stderr


@pytest.mark.procs
@pytest.mark.parametrize(("package", "extra", "args"), [
    ("sklearn", "analysis", ["repro", "fig10", "--out", "OUT"]),
    ("cryptography", "secure", ["certs", "--out", "OUT", "--robots", "2"]),
    ("mcap", "record", ["record", "--run-id", "r", "--out", "OUT/r.mcap"]),
])
def test_a_missing_extra_is_one_line_naming_it(tmp_path: Path, package: str, extra: str,
                                               args: list[str]) -> None:
    """UA pass: without scikit-learn, `swarm repro fig10` was a 20-line traceback, and the
    hints said `pip install -e '.[EXTRA]'`, which fails outside the repository root. Without
    the package (an import of it fails), one line naming the extra, exit status 2."""
    blocked = tmp_path / "blocked" / package
    blocked.mkdir(parents=True)
    (blocked / "__init__.py").write_text(f"raise ImportError('no {package} here')\n")
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(blocked.parent), str(ROOT)])}
    r = subprocess.run([sys.executable, "-m", "swarm.cli",
                        *(a.replace("OUT", str(tmp_path)) for a in args)],
                       cwd=tmp_path, capture_output=True, text=True, timeout=300, env=env)
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1, r.stderr
    assert f"pip install 'commattn-swarm[{extra}]'" in r.stderr, r.stderr


def test_the_all_extra_is_every_optional_feature() -> None:
    """`commattn-swarm[all]` installs every extra but the test tools, and those extras are the
    ones the README and docs/DECISIONS.md list."""
    import tomllib

    extras = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"][
        "optional-dependencies"]
    features = set(extras) - {"all", "test"}
    [every] = extras["all"]
    name, _, listed = every.rstrip("]").partition("[")
    assert name == "commattn-swarm" and set(listed.split(",")) == features, every
    decisions = " ".join((ROOT / "docs" / "DECISIONS.md").read_text().split())
    assert all(f"`{name}` (" in decisions for name in [*features, "all", "test"])
