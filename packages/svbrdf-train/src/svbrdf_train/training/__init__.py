"""A fit: the GAN trainer and everything one training step and one fit need.

- :mod:`~svbrdf_train.training.trainer` (the fit), :mod:`~svbrdf_train.training.step` (one step),
  :mod:`~svbrdf_train.training.losses` (the paper's losses, with the weights of
  :mod:`~svbrdf_train.recipe.paper_weights`), :mod:`~svbrdf_train.training.schedule` (learning rates);
- :mod:`~svbrdf_train.training.clock`, :mod:`~svbrdf_train.training.checkpoint`,
  :mod:`~svbrdf_train.training.resume`, :mod:`~svbrdf_train.training.order` (budgets, saving and
  resuming bit for bit), :mod:`~svbrdf_train.training.init` (fine-tuning);
- :mod:`~svbrdf_train.training.run` (a fit's run, and the read-only view its hooks get),
  :mod:`~svbrdf_train.training.hooks` (what runs between steps), :mod:`~svbrdf_train.training.validation`,
  :mod:`~svbrdf_train.training.fitlog`, :mod:`~svbrdf_train.training.progress`,
  :mod:`~svbrdf_train.training.flops`, :mod:`~svbrdf_train.training.distributed`.

The public names are importable from :mod:`svbrdf_train` itself.
"""

# Nothing of its own: the training's public names are svbrdf_train's own.
__all__: list[str] = []
