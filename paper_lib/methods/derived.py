"""Tensors derived from a layer's parameters (gathered Masksembles weights, kept units), kept across calls.

Gathering member j's weights on its kept units, W[kept_out_j][:, kept_in_j], copies them (~0.5 ms for a
256-wide MLP, as long as the products of a few hundred states), and finding the kept units of a mask costs a
handful of small ops: done per call, both showed up in every inference call. Here they are made once and
remade only when a source tensor changed:
- modified in place (its version counter moves: optimizer steps, `load_state_dict`, `mask.masks[...] = 0`);
- replaced by other memory (`param.data = ...`, `.to()`): its address moves. The entry holds an alias of
  each source, so the old memory cannot be reused at the same address while the entry lives.
A derived tensor holds the same values as one made afresh: the numbers do not depend on the cache.
"""

from __future__ import annotations

import weakref
from collections.abc import Callable
from typing import TypeVar

import torch as th
from torch import nn

T = TypeVar("T")

_ENTRIES: weakref.WeakKeyDictionary[nn.Module, dict[str, tuple]] = weakref.WeakKeyDictionary()


def _key(sources: tuple[th.Tensor | None, ...]) -> tuple:
    # an inference tensor (made under th.inference_mode) has no version counter; it cannot be modified in place
    # outside inference mode either
    return tuple(None if s is None else (s.data_ptr(), -1 if s.is_inference() else s._version) for s in sources)


def derived(module: nn.Module, tag: str, sources: tuple[th.Tensor | None, ...], make: Callable[[], T]) -> T:
    """`make()`, computed from `sources` (tensors or None), remade only when one of them changed."""
    entries = _ENTRIES.get(module)
    if entries is None:
        entries = _ENTRIES[module] = {}
    key = _key(sources)
    entry = entries.get(tag)
    if entry is None or entry[0] != key:
        with th.no_grad():
            value = make()
        entry = entries[tag] = (key, tuple(None if s is None else s.detach() for s in sources), value)
    return entry[2]
