"""``svbrdf-train recipes``: the recipes that can be trained, and what one resolves to."""

from __future__ import annotations

import click

from ..recipe import SIZES
from .options import explicit


@click.command("recipes")
@click.argument("name", required=False, metavar="[NAME|FILE]")
@click.option(
    "--size", type=click.Choice(SIZES), default="paper", show_default=True, help="Size to resolve NAME at."
)
@click.option("--set", "sets", multiple=True, metavar="SECTION.FIELD=VALUE", help="Overrides, as for fit.")
@click.pass_context
def recipes(ctx, name, size, sets):
    """List the recipes (built-in and from plugins), or print one fully resolved as YAML.

    \b
      svbrdf-train recipes                      # names and descriptions
      svbrdf-train recipes ours --size cpu      # every field fit would use
    """
    import yaml

    from ..recipe import list_recipes, load_recipe, parse_overrides, recipe_path

    if name is None and (sets or explicit(ctx, "size")):
        given = " ".join(
            [*(f"--set {x}" for x in sets), *([f"--size {size}"] if explicit(ctx, "size") else [])]
        )
        raise click.UsageError(f"{given}: resolves one recipe; give its NAME or FILE (the list ignores it)")
    if name is not None:
        recipe = load_recipe(name, size, parse_overrides(sets))
        click.echo(yaml.safe_dump(recipe.to_dict(), sort_keys=False), nl=False)
        return
    names = list_recipes()
    width = max(map(len, names), default=0)
    for n in names:
        try:
            description = load_recipe(n).description
        except Exception as e:  # a broken plugin recipe is listed with its error, not fatal
            description = f"(cannot be read: {e})"
        click.echo(f"{n:<{width}}  {description}")
    click.echo(f"\nsizes: {', '.join(SIZES)}; files: {recipe_path(names[0]).parent if names else '-'}")


COMMANDS = [recipes]
