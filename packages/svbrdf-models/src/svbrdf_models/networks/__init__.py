"""The networks: generators, attention modules, discriminators and the untrained baselines.

- :mod:`~svbrdf_models.networks.generators`: the U-Net generator and its variants (``ours``,
  ``unet``, ``no-attn``, ...);
- :mod:`~svbrdf_models.networks.attention`: the attention modules a generator embeds;
- :mod:`~svbrdf_models.networks.discriminators`: PatchGAN and the multi-GAN discriminator;
- :mod:`~svbrdf_models.networks.baselines`: ``mean`` and ``photo``, generators without trained
  parameters.

They register through entry points like any plugin (:mod:`svbrdf_models._registry`), and load
on first use: ``svbrdf_models.create_generator("ours", ...)``; the classes are public names of
:mod:`svbrdf_models`.
"""

# Nothing of its own: the networks' public names are svbrdf_models' own (its lazy table).
__all__: list[str] = []
