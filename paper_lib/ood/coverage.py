"""Did the agent's own ID rollouts ever reach the Atari OOD states? One row per run.

An edited game state (a later level, maze or room) only gives OOD states if the trained agent
never gets there by itself. Berzerk's rooms are the weakest case: a good agent may well enter
ten rooms in one game. So ``collect_id_states`` records, for every ID state it keeps, the OOD
source's indicator (the RAM byte the source sets, e.g. Berzerk's room counter, RAM 92; or the
ALE mode the env runs, which ID play cannot change), and ``source_coverage`` compares the
values the ID states had with the values the OOD source sets. It reads the dataset only: the
check rests on exactly the rollouts the ID set comes from, and is as deterministic as they are.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pandas as pd

from paper_lib.ood.atari import ATARI_GAMES, DEFAULT_SOURCE, indicator_name, source_values
from paper_lib.ood.atari_head import HEAD_KIND, HEAD_SOURCE
from paper_lib.ood.datasets import ID_LABEL, NOT_RECORDED, OOD_LABEL, StateDataset

#: The columns of ``source_coverage``'s row, in order.
COVERAGE_COLUMNS = ("game", "ood_source", "indicator", "ood_values", "n_id_states", "n_id_recorded", "id_min",
                    "id_max", "id_values", "id_states_at_ood_values", "id_share_at_ood_values",
                    "ood_share_at_ood_values", "check")
PASSED, FAILED, NOT_CHECKED = "passed", "failed: ID play reached OOD values", "not recorded: recollect the dataset"
STALE = "stale: the ID states recorded another indicator than the source's today; recollect the dataset"
HUMAN_PLAY = "not applicable: Atari-HEAD human play has no game-state indicator to compare"


def _values_text(values: Any) -> str:
    """Sorted distinct ints as "0;1;2", one CSV cell."""
    return ";".join(str(int(v)) for v in sorted(set(np.asarray(values).tolist())))


def _parts(dataset: StateDataset) -> list[dict[str, Any]]:
    """The metadata of each collection the dataset was concatenated from (itself if none)."""
    return dataset.metadata.get("parts") or [dataset.metadata]


def _game_of(dataset: StateDataset, game: str | None) -> str:
    """The Atari game the dataset was collected in; ``game``, if given, must agree."""
    env_ids = {p["env_id"] for p in _parts(dataset) if "env_id" in p}
    found = {e.removesuffix("NoFrameskip-v4") for e in env_ids}
    if game is not None and game not in ATARI_GAMES:
        raise ValueError(f"game={game!r}: use one of {list(ATARI_GAMES)} (no 'NoFrameskip-v4').")
    if game is None and len(found) != 1:
        raise ValueError(f"the dataset's metadata names env ids {sorted(env_ids)}: pass game= one of "
                         f"{list(ATARI_GAMES)}.")
    game = game or found.pop()
    if game not in ATARI_GAMES:
        raise ValueError(f"the dataset was collected in {sorted(env_ids)}, not an Atari game of the benchmark "
                         f"({list(ATARI_GAMES)}): the source coverage check applies to Atari datasets only.")
    if env_ids and env_ids != {f"{game}NoFrameskip-v4"}:
        raise ValueError(f"game={game!r} but the dataset was collected in {sorted(env_ids)}: pass its own game.")
    return game


def _sources(dataset: StateDataset, game: str) -> tuple[str, str | None]:
    """(the OOD states' source, the source whose indicator the ID states recorded or None)."""
    parts = _parts(dataset)
    ood = [p.get("source") or DEFAULT_SOURCE[game] for p in parts if p.get("kind") == "atari_ood"]
    recorded = [(p.get("source_indicator") or {}).get("source") for p in parts if p.get("kind") == "id"]
    recorded_source = next((r for r in recorded if r), None)
    if len(set(ood)) > 1:
        raise ValueError(f"the dataset holds OOD states of several sources {sorted(set(ood))}: check each "
                         "collection on its own (dataset.subset).")
    ood_source = ood[0] if ood else recorded_source or DEFAULT_SOURCE[game]
    if recorded_source is not None and recorded_source != ood_source:
        raise ValueError(f"the ID states recorded the indicator of source {recorded_source!r} but the OOD states come "
                         f"from {ood_source!r}: collect the ID states with indicator_source={ood_source!r}.")
    return ood_source, recorded_source


def _recorded_read(dataset: StateDataset) -> str | None:
    """What the ID states' indicator read when they were collected ("RAM 60", ...), None if not said."""
    reads = [(p.get("source_indicator") or {}).get("read") for p in _parts(dataset) if p.get("kind") == "id"]
    return next((r for r in reads if r), None)


def source_coverage(dataset: StateDataset, game: str | None = None) -> pd.DataFrame:
    """One row: the indicator values the ID states reached, and whether any is an OOD value.

    ``check`` is "passed" (no ID state at an OOD value), "failed: ..." (some were: the source
    does not give unseen states for this agent), "not recorded: ..." (a dataset collected
    before the indicator was recorded; the counts are then empty) or "stale: ..." (the ID states
    read another quantity than the source's indicator reads today, e.g. Seaquest's RAM 61 before
    it became RAM 60; ``indicator`` then names what was read). ``ood_share_at_ood_values``
    shows the edit in force on the OOD states (below 1 where play moves a counter on, e.g.
    Berzerk's rooms after a death). ``game`` defaults to the one in the dataset's metadata.
    """
    if not isinstance(dataset, StateDataset):
        raise TypeError(f"expected a StateDataset, got {type(dataset).__name__}.")
    game = _game_of(dataset, game)
    if any(p.get("kind") == HEAD_KIND for p in _parts(dataset)):
        return _human_play_row(dataset, game)
    ood_source, recorded_source = _sources(dataset, game)
    ood_values = np.array(source_values(game, ood_source))
    is_id = dataset.labels == ID_LABEL
    indicator = dataset.source_indicator
    if indicator is None:
        indicator = np.full(len(dataset), NOT_RECORDED, dtype=np.int16)
    id_values = indicator[is_id & (indicator != NOT_RECORDED)] if recorded_source else indicator[:0]
    ood_states = (dataset.labels == OOD_LABEL) & (dataset.source == ood_source) & (indicator != NOT_RECORDED)
    at_ood = np.isin(id_values, ood_values)
    recorded = len(id_values) > 0
    read_now = indicator_name(game, ood_source)
    read_then = _recorded_read(dataset) or read_now  # datasets older than the recorded "read" are taken as today's
    check = NOT_CHECKED if not recorded else STALE if read_then != read_now else FAILED if at_ood.any() else PASSED
    row = {
        "game": game, "ood_source": ood_source, "indicator": read_then,
        "ood_values": _values_text(ood_values), "n_id_states": int(is_id.sum()), "n_id_recorded": len(id_values),
        "id_min": int(id_values.min()) if recorded else None, "id_max": int(id_values.max()) if recorded else None,
        "id_values": _values_text(id_values), "id_states_at_ood_values": int(at_ood.sum()),
        "id_share_at_ood_values": float(at_ood.mean()) if recorded else np.nan,
        "ood_share_at_ood_values": (float(np.isin(indicator[ood_states], ood_values).mean()) if ood_states.any()
                                    else np.nan),
        "check": check,
    }
    return _frame(row)


def _human_play_row(dataset: StateDataset, game: str) -> pd.DataFrame:
    """Atari-HEAD OOD states (human play at advanced levels) carry no indicator: nothing to check here."""
    is_id = dataset.labels == ID_LABEL
    row = {"game": game, "ood_source": HEAD_SOURCE, "indicator": None, "ood_values": "",
           "n_id_states": int(is_id.sum()), "n_id_recorded": 0, "id_min": None, "id_max": None, "id_values": "",
           "id_states_at_ood_values": 0, "id_share_at_ood_values": np.nan, "ood_share_at_ood_values": np.nan,
           "check": HUMAN_PLAY}
    return _frame(row)


def _frame(row: dict[str, Any]) -> pd.DataFrame:
    frame = pd.DataFrame([row], columns=list(COVERAGE_COLUMNS))
    return frame.astype({"id_min": "Int64", "id_max": "Int64"})
