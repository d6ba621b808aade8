"""One shape for every "unknown key" and "missing key" error, wherever a settings mapping is read.

params.yaml's sections (profiles, hyperparameters, retraining, study, scaling, guard, ensembles) and the
hyperparameter entries make_agent receives are all checked with `check_keys`, so a typo reads the same
wherever it is made. Layer 0: it knows nothing of the paper.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any


def check_keys(mapping: Any, where: str, known: Iterable[Any], required: Iterable[Any] = (), *, what: str = "key",
               fix: str = "copy them from another profile in params.yaml") -> dict[Any, Any]:
    """`mapping`, once its keys are all `known` and hold every `required` one; else one ValueError naming them.

    Every section of params.yaml is checked with this, so a typo or a missing key reads the same wherever it is
    made: `<where>: unknown <what>(s) [...]; known: [...]`, or `<where> lacks [...]; <fix>`.
    """
    if not isinstance(mapping, dict):
        raise ValueError(f"{where} must be a mapping (key: value), got {mapping!r}")
    known = list(known)
    unknown = sorted(set(mapping) - set(known), key=str)
    if unknown:
        raise ValueError(f"{where}: unknown {what}(s) {unknown}; known: {known}")
    missing = [key for key in required if key not in mapping]
    if missing:
        raise ValueError(f"{where} lacks {missing}; {fix}")
    return mapping

