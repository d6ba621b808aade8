"""Did the trained agent reach the Atari OOD source's values anywhere in a whole game? One row per run.

The companion of ``paper_lib.ood.coverage``, which checks the benchmark's ID states. Those cover only
the first steps of episodes (the same part as the OOD states), while a good agent gets to later
levels and rooms later in a game. The evaluation games are whole games, and each of their rows
records the highest value of the default source's indicator (``paper_lib.scoring.rewards``), so a
source is trusted only if no game reached its values either.
"""

from __future__ import annotations

import numpy as np
import pandas as pd

from paper_lib.agents.envs import is_atari
from paper_lib.ood.atari import DEFAULT_SOURCE, game_of, source_values


#: The columns of ``play_coverage``'s rows, in order (after env, method, seed).
PLAY_COLUMNS = ("games", "games_recorded", "play_max", "games_at_ood_values", "play_check")
PLAY_PASSED, PLAY_FAILED = "passed", "failed: full games reached OOD values"
PLAY_NOT_RECORDED = "not recorded: evaluate the run again"


def play_coverage(episodes: pd.DataFrame) -> pd.DataFrame:
    """Per Atari run: did the agent reach the default OOD source's values anywhere in its evaluation games?

    ``episodes`` are evaluation rows (`paper_lib.scoring.rewards.evaluate_rewards`, with env, method and
    seed) whose ``source_indicator_max`` is the highest indicator value of each whole game. The ID
    states of the benchmark cover only the first steps of episodes; a whole game is where a good
    agent gets to later levels and rooms, so this is the stronger check. Non-Atari rows are left out.
    """
    missing = {"env", "method", "seed"} - set(episodes.columns)
    if missing:
        raise ValueError(f"play_coverage needs evaluation rows with columns env, method and seed; missing {sorted(missing)}.")
    rows = []
    for (env_id, method, seed), games in episodes.groupby(["env", "method", "seed"], sort=False):
        if not is_atari(env_id):
            continue
        game = game_of(env_id)
        values = np.array(source_values(game, DEFAULT_SOURCE[game]))
        reached = games["source_indicator_max"].dropna() if "source_indicator_max" in games else pd.Series([], dtype=float)
        at_ood = np.isin(reached.astype(int), values)
        rows.append({"env": env_id, "method": method, "seed": seed, "games": len(games), "games_recorded": len(reached),
                     "play_max": int(reached.max()) if len(reached) else None, "games_at_ood_values": int(at_ood.sum()),
                     "play_check": (PLAY_NOT_RECORDED if not len(reached) else PLAY_FAILED if at_ood.any()
                                    else PLAY_PASSED)})
    return pd.DataFrame(rows, columns=["env", "method", "seed", *PLAY_COLUMNS]).astype({"play_max": "Int64"})
