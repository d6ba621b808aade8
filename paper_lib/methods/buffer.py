"""The member-ordered rollout buffer: the `own` assignment of transitions to members.

With SB3's RolloutBuffer every minibatch is a random draw from the whole shared buffer and
chunk j goes through member j (the paper's `shared` assignment). This buffer orders every
minibatch by member instead: chunk j holds only transitions collected by member j's env
group, so each transition is evaluated by the member that acted and its PPO ratio stays
on-policy. Pass it as PPO(..., rollout_buffer_class=MemberOrderedRolloutBuffer,
rollout_buffer_kwargs={"n_members": k}).
"""

from __future__ import annotations

from collections.abc import Generator

import numpy as np
from stable_baselines3.common.buffers import RolloutBuffer
from stable_baselines3.common.type_aliases import RolloutBufferSamples

from paper_lib.methods.groups import check_member_layout


class MemberOrderedRolloutBuffer(RolloutBuffer):
    def __init__(self, *args, n_members: int, **kwargs):
        super().__init__(*args, **kwargs)
        check_member_layout(self.n_envs, n_members)
        self.n_members = n_members

    def member_ordered_indices(self, batch_size: int) -> np.ndarray:
        """A permutation whose consecutive batch_size slices hold batch_size/k rows per member, in member order.

        After SB3's swap_and_flatten, flat index = env * n_steps + step, so member g's
        transitions are the contiguous block g of k equal blocks.
        """
        total = self.buffer_size * self.n_envs
        check_member_layout(self.n_envs, self.n_members, batch_size, self.buffer_size)
        batch_size = min(batch_size, total)  # a larger batch is one minibatch of the whole rollout, as in SB3
        block = total // self.n_members
        chunk = batch_size // self.n_members
        per_member = [g * block + np.random.permutation(block) for g in range(self.n_members)]
        # (k, n_batches, chunk) -> (n_batches, k, chunk): batch b = chunk b of every member, in member order
        stacked = np.stack([p.reshape(-1, chunk) for p in per_member])
        return stacked.transpose(1, 0, 2).reshape(-1)

    def get(self, batch_size: int | None = None) -> Generator[RolloutBufferSamples, None, None]:
        assert self.full, ""
        total = self.buffer_size * self.n_envs
        batch_size = total if batch_size is None else min(batch_size, total)
        indices = self.member_ordered_indices(batch_size)
        if not self.generator_ready:
            for name in ("observations", "actions", "values", "log_probs", "advantages", "returns"):
                self.__dict__[name] = self.swap_and_flatten(self.__dict__[name])
            self.generator_ready = True
        for start in range(0, total, batch_size):
            yield self._get_samples(indices[start : start + batch_size])
