"""The project used as a Python library: wrong arguments to the world's and the policies' public
functions are one-line errors naming the bad item, not silent wrong figures or numpy
tracebacks (user-acceptance findings)."""

from __future__ import annotations

import numpy as np
import pytest

from world import core
from world.config import ConfigError, WorldConfig
from world.decentral import batch_view, traj_messages

CFG = WorldConfig(n_robots=3)


@pytest.mark.parametrize("other, named", [
    (WorldConfig(n_robots=3, height=25, width=25), "height 25 (state's: 20), width 25"),
    (WorldConfig(n_robots=3, vision=7), "vision 7 (state's: 5)"),
    (WorldConfig(n_robots=3, horizon=10), "horizon 10 (state's: 30)")])
def test_a_state_refuses_a_config_it_was_not_reset_with(other: WorldConfig, named: str) -> None:
    """A 25 x 25 config on a 20 x 20 state divided elratio by 625 cells and decoded positions
    on the wrong row width without a word; every (cfg, state) function now refuses it."""
    state = core.reset(CFG, 0, [0])
    calls = [lambda: core.step(other, state, np.full((1, 3), 3)), lambda: core.metrics(other, state),
             lambda: batch_view(other, state), lambda: core.patches(other, state),
             lambda: core.elratio(other, state), lambda: traj_messages(other, state)]
    for call in calls:
        with pytest.raises(ConfigError, match="differs from the one the state was reset with") as e:
            call()
        assert named in str(e.value) and "\n" not in str(e.value)
    assert state.t == 0
    same = WorldConfig(n_robots=3)  # an equal config (not the same object) is the same world
    core.step(same, state, np.full((1, 3), 3))
    assert core.metrics(same, state).elratio.shape == (1,) and batch_view(same, state).tick == 1
