"""The order of the training batches, which a resumed fit continues exactly.

Step ``s`` of a fit takes batch ``s mod steps_per_epoch`` of epoch ``s // steps_per_epoch``:
each epoch's order is a :class:`~torch.utils.data.DistributedSampler` shuffle seeded by
``(train.seed, epoch)``, split between the processes, ``train.batch`` samples each per step.
Nothing depends on how the fit got to step ``s``, so a fit resumed there takes the same batch
as one that never stopped (:class:`From` skips the epoch's batches already trained on).

Where the batches are made (``data.generate``):

- ``workers``: a DataLoader with ``data.workers`` CPU processes, each seeded from
  ``(train.seed, epoch)``, never from the global random state (which would then depend on
  how often a loader was made: resuming mid-epoch makes one more);
- ``device``: in the training process, on the training device, one batch at a time
  (:func:`svbrdf_train.data.fitdata.device_batch`): procedural materials and their photos are
  computed there, other sources are read on the CPU and moved.
"""

from __future__ import annotations

from collections.abc import Iterator

import torch
from torch.utils.data import DataLoader, Dataset, DistributedSampler, Sampler

from ..errors import TrainingError
from ..recipe import Recipe

__all__ = ["BatchOrder", "From"]


class From(Sampler[int]):
    """The indices of ``sampler`` from position ``start`` on (to resume mid-epoch)."""

    def __init__(self, sampler: Sampler[int], start: int, length: int):
        self.sampler, self.start, self.length = sampler, start, length

    def __iter__(self) -> Iterator[int]:
        for i, index in enumerate(self.sampler):
            if i >= self.length:
                return
            if i >= self.start:
                yield index

    def __len__(self) -> int:
        return self.length - self.start


class BatchOrder:
    """The batches of one process, from any step to the end of the step budget (module doc).

    Args:
        data: the training set.
        recipe: its ``train`` (batch, epochs, max_steps, seed) and ``data`` (workers,
            generate) fields.
        rank, world: this process and how many there are.
        device: the training device (pinned memory there; batches made there with
            ``data.generate: device``).
    """

    def __init__(self, data: Dataset, recipe: Recipe, rank: int, world: int, device: torch.device):
        self.data, self.recipe, self.rank, self.world, self.device = data, recipe, rank, world, device
        t = recipe.train
        self.steps_per_epoch = len(data) // (t.batch * world)
        if self.steps_per_epoch == 0:
            raise TrainingError(
                f"{recipe.source}: {len(data)} training samples do not fill one step of "
                f"{t.batch} x {world} process(es); lower train.batch or add data (data.count)"
            )
        total = t.epochs * self.steps_per_epoch
        self.total_steps = min(total, t.max_steps) if t.max_steps is not None else total

    @property
    def epoch_samples(self) -> int:
        """Samples in one epoch of all processes together."""
        return self.steps_per_epoch * self.recipe.train.batch * self.world

    def batches(self, step: int) -> Iterator[dict]:
        """The batches of steps ``step``, ``step + 1``, ... up to the step budget."""
        from ..data.fitdata import set_epoch

        while step < self.total_steps:
            epoch, offset = divmod(step, self.steps_per_epoch)
            set_epoch(self.data, epoch)
            last = min(self.steps_per_epoch, offset + self.total_steps - step)
            indices = self._indices(epoch, offset, last)
            for batch in self._make(indices, epoch):
                yield batch
                step += 1

    def _indices(self, epoch: int, first: int, last: int) -> From:
        """This process's sample indices of batches ``first:last`` of ``epoch``."""
        t = self.recipe.train
        sampler = DistributedSampler(
            self.data, num_replicas=self.world, rank=self.rank, shuffle=True, seed=t.seed, drop_last=True
        )
        sampler.set_epoch(epoch)
        return From(sampler, first * t.batch, last * t.batch)

    def _make(self, indices: From, epoch: int) -> Iterator[dict]:
        batch = self.recipe.train.batch
        if self.recipe.data.generate == "device":
            from ..data.fitdata import device_batch

            chosen = list(indices)
            for k in range(0, len(chosen), batch):
                yield device_batch(self.data, chosen[k : k + batch], self.device)
            return
        yield from DataLoader(
            self.data,
            batch_size=batch,
            sampler=indices,
            num_workers=self.recipe.data.workers,
            drop_last=True,
            pin_memory=self.device.type == "cuda",
            generator=torch.Generator().manual_seed(self.recipe.train.seed * 100_003 + epoch),
        )
