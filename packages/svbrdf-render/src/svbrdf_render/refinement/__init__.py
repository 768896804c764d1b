"""Refinement: maps optimised through the renderer until they explain a photo.

- :mod:`~svbrdf_render.refinement.refine`: :func:`refine_maps`, its settings, priors and loss (the
  prior term :func:`refine_views` adds too);
- :mod:`~svbrdf_render.refinement.views`: :func:`refine_views`, one material refined against
  several photos, each under its own camera and light;
- :mod:`~svbrdf_render.refinement.rings`: the flash's rings (the highlight found on a photo, the
  ring penalty, de-ringing);
- :mod:`~svbrdf_render.refinement.falloff`: where the flash stood, read off the fall-off of its
  light over a photo;
- :mod:`~svbrdf_render.refinement.fit`: the flash found from maps and a photo (``axis_flash``,
  ``fit_flash``) and the Adam both step.

The public names are importable from :mod:`svbrdf_render` itself.
"""

# Nothing of its own: the refinement's public names are svbrdf_render's own.
__all__: list[str] = []
