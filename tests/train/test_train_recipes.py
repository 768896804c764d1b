"""Recipes: the built-ins at every size, overrides, and errors that name the field and the file."""

from __future__ import annotations

import pytest
import yaml

from svbrdf_train.errors import RecipeError
from svbrdf_train.recipe import SIZES, list_recipes, load_recipe, parse_overrides

BUILTIN = ["ours", "no-attn", "no-attn-wide", "no-adv", "no-svbrdf", "multigan", "radn"]


def test_builtin_recipes_are_registered():
    assert set(BUILTIN) <= set(list_recipes())


@pytest.mark.parametrize("size", SIZES)
@pytest.mark.parametrize("name", BUILTIN)
def test_every_builtin_loads_at_every_size(name, size):
    r = load_recipe(name, size)
    assert r.name == name and r.size == size and r.description
    assert (r.discriminator is None) == (r.loss.adv == 0)
    if size == "paper":
        assert (r.train.resolution, r.train.batch, r.train.epochs) == (256, 8, 20)
        assert r.optim.lr == 2e-5 and r.optim.g_steps_per_d == 5 and r.optim.decay_every_samples == 400_000
    else:
        assert r.train.resolution < 256 and r.generator.config.get("preset") in ("small", "tiny")
    assert yaml.safe_load(yaml.safe_dump(r.to_dict())) == r.to_dict()


def test_the_ablations_differ_from_ours_in_what_the_paper_says():
    ours = load_recipe("ours")
    assert (ours.generator.name, ours.discriminator.name) == ("ours", "patchgan")
    assert (ours.loss.adv, ours.loss.render, ours.loss.svbrdf) == (0.1, 0.5, 0.5)
    assert ours.loss.maps == {"normal": 1.0, "diffuse": 1.0, "roughness": 0.5, "specular": 0.5}
    assert load_recipe("no-attn").generator.name == "no-attn"
    no_adv = load_recipe("no-adv")
    assert no_adv.loss.adv == 0 and no_adv.discriminator is None
    assert load_recipe("no-svbrdf").loss.svbrdf == 0
    assert load_recipe("multigan").discriminator.name == "multi"
    radn = load_recipe("radn")
    assert radn.generator.name == "no-attn" and radn.discriminator is None
    assert (radn.loss.adv, radn.loss.svbrdf) == (0, 0) and radn.loss.render > 0
    # Everything not named stays as in ours.
    assert load_recipe("multigan").optim == ours.optim and load_recipe("no-attn").train == ours.train


def _generator_parameters(name: str, size: str) -> int:
    """Parameters of recipe ``name``'s generator at ``size``, built on the meta device (no memory)."""
    import torch

    import svbrdf_models as sm

    r = load_recipe(name, size)
    with torch.device("meta"):
        g = sm.create_generator(r.generator.name, r.generator.config)
    return sum(p.numel() for p in g.parameters())


@pytest.mark.parametrize("size", SIZES)
def test_the_capacity_control_has_the_parameters_of_ours_and_no_attention(size):
    """no-attn-wide tells "attention helps" from "more parameters help": its generator is within
    5% of ours' parameter count at every size, where no-attn's is nearly half of it."""
    ours = _generator_parameters("ours", size)
    assert abs(_generator_parameters("no-attn-wide", size) / ours - 1) <= 0.05
    assert abs(_generator_parameters("no-attn", size) / ours - 1) > 0.05  # the gap the control closes
    wide, plain = load_recipe("no-attn-wide", size), load_recipe("no-attn", size)
    assert wide.generator.name == "no-attn" and wide.train == plain.train and wide.loss == plain.loss
    assert wide.discriminator == plain.discriminator and wide.optim == plain.optim


def test_overrides_from_the_command_line():
    r = load_recipe("ours", "smoke", parse_overrides(["loss.adv=0", "train.batch=4", "generator.config.attention=se"]))
    assert r.discriminator is None and r.train.batch == 4
    assert r.generator.config == {"preset": "tiny", "attention": "se"}
    r = load_recipe("ours", overrides=parse_overrides(["loss.maps.normal=2", "data.path=[a.h5, b.h5]", "data.source=shards"]))
    assert r.loss.maps["normal"] == 2 and r.loss.maps["roughness"] == 0.5
    assert r.data.path == ("a.h5", "b.h5")


def test_a_user_file_can_start_from_a_builtin(tmp_path):
    f = tmp_path / "mine.yaml"
    f.write_text("base: ours\ndescription: mine\ngenerator: {name: ours, config: {attention: cbam}}\n")
    r = load_recipe(f, "smoke")
    assert r.name == "mine" and r.generator.config == {"attention": "cbam", "preset": "tiny"}
    assert r.source == str(f)


def write(tmp_path, text):
    f = tmp_path / "r.yaml"
    f.write_text(text)
    return f


def test_unknown_field_in_a_file_names_it_and_the_file(tmp_path):
    f = write(tmp_path, "base: ours\nloss: {advv: 0.2}\n")
    with pytest.raises(RecipeError) as e:
        load_recipe(f)
    assert "'advv'" in str(e.value) and str(f) in str(e.value) and "'adv'" in str(e.value)


def test_unknown_section_names_it(tmp_path):
    f = write(tmp_path, "base: ours\noptimiser: {lr: 1}\n")
    with pytest.raises(RecipeError, match="unknown section 'optimiser'.*did you mean 'optim'"):
        load_recipe(f)


def test_unknown_field_on_the_command_line_names_it_and_the_recipe():
    with pytest.raises(RecipeError) as e:
        load_recipe("ours", overrides=parse_overrides(["train.bach=4"]))
    msg = str(e.value)
    assert "'train.bach'" in msg and "'batch'" in msg and "ours.yaml" in msg
    with pytest.raises(RecipeError, match="unknown section 'trian'"):
        load_recipe("ours", overrides=parse_overrides(["trian.batch=4"]))
    with pytest.raises(RecipeError, match="section.field=value"):
        parse_overrides(["batch=4"])


def test_wrong_types_and_values_name_the_field(tmp_path):
    with pytest.raises(RecipeError, match="'batch' expects int"):
        load_recipe("ours", overrides={"train.batch": "eight"})
    with pytest.raises(RecipeError, match="'gan' must be one of"):
        load_recipe("ours", overrides={"loss.gan": "wgan"})
    with pytest.raises(RecipeError, match=r"generator: .*unknown preset 'huge'"):
        load_recipe("ours", overrides={"generator.config.preset": "huge"})
    # A real source without a path loads (ours-real gets it from --data) and is refused at fit time.
    from svbrdf_models.errors import DataError
    from svbrdf_train.data.fitdata import build_datasets

    with pytest.raises(DataError, match="needs a path: give --data"):
        build_datasets(load_recipe("ours", overrides={"data.source": "shards"}))


def test_adversarial_weight_needs_a_discriminator():
    with pytest.raises(RecipeError, match="loss.adv is 0.1 but no discriminator"):
        load_recipe("no-adv", overrides={"loss.adv": 0.1})
    # Naming one on the command line turns it back on.
    r = load_recipe("no-adv", overrides={"loss.adv": 0.1, "discriminator.name": "patchgan"})
    assert r.discriminator.name == "patchgan"


def test_unknown_recipe_size_and_bad_files(tmp_path):
    with pytest.raises(RecipeError, match="unknown recipe 'our'.*Did you mean 'ours'"):
        load_recipe("our")
    with pytest.raises(RecipeError, match="no size 'gpu'"):
        load_recipe("ours", "gpu")
    with pytest.raises(RecipeError, match="not valid YAML"):
        load_recipe(write(tmp_path, "loss: {adv: [\n"))
    with pytest.raises(RecipeError, match="not found"):
        load_recipe(tmp_path / "missing.yaml")
    a, b = tmp_path / "a.yaml", tmp_path / "b.yaml"
    a.write_text(f"base: {b}\n")
    b.write_text(f"base: {a}\n")
    with pytest.raises(RecipeError, match="loop"):
        load_recipe(a)


def test_a_file_reads_exponent_numbers_as_the_command_line_does(tmp_path):
    # YAML 1.1 reads 3e-4 as a string: the file was refused while --set optim.lr=3e-4 passed.
    f = write(tmp_path, "base: ours\noptim: {lr: 3e-4, d_lr: 1e-3}\ndata: {count: 1e5}\n")
    with pytest.raises(RecipeError, match=r"'count' expects int, got 100000.0"):
        load_recipe(f)  # a float is still no sample count
    f = write(tmp_path, "base: ours\noptim: {lr: 3e-4, d_lr: 1e-3}\n")
    r = load_recipe(f)
    assert (r.optim.lr, r.optim.d_lr) == (3e-4, 1e-3)
    assert r.optim == load_recipe("ours", overrides=parse_overrides(["optim.lr=3e-4", "optim.d_lr=1e-3"])).optim


def test_a_relative_base_is_read_from_the_recipe_folder_not_the_current_one(tmp_path, monkeypatch):
    mine = tmp_path / "recipes"
    (mine / "parts").mkdir(parents=True)
    (mine / "parts" / "common.yaml").write_text("base: ours\ntrain: {batch: 3}\n")
    (mine / "child.yaml").write_text("base: parts/common.yaml\noptim: {lr: 1e-4}\n")
    (mine / "grandchild.yaml").write_text("base: ./child.yaml\ndescription: deeper\n")
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)
    r = load_recipe(mine / "grandchild.yaml")
    assert (r.train.batch, r.optim.lr, r.description) == (3, 1e-4, "deeper")
    # A name still means a registered recipe; a missing relative file names where it was looked for.
    assert load_recipe(mine / "child.yaml", "smoke").generator.config["preset"] == "tiny"
    (mine / "bad.yaml").write_text("base: missing.yaml\n")
    with pytest.raises(RecipeError, match=r"bad.yaml: base: 'missing.yaml': no file .*recipes/missing.yaml"):
        load_recipe(mine / "bad.yaml")
    (mine / "typo.yaml").write_text("base: ourz\n")
    with pytest.raises(RecipeError, match=r"typo.yaml: base: unknown recipe 'ourz'.*'ours'"):
        load_recipe(mine / "typo.yaml")


def test_overrides_of_a_loaded_recipe_and_checkpoint_recipes_are_checked_alike():
    from svbrdf_train.recipe import recipe_from_dict, with_overrides

    r = load_recipe("ours", "smoke")
    with pytest.raises(RecipeError, match=r"--set train.resolution=30 \(recipe .*ours.yaml\): train.resolution is 30, but generator 'ours'.*multiples of 16"):
        with_overrides(r, {"train.resolution": 30})  # what fit --resume --set does
    data = r.to_dict()
    data["optim"]["lr"] = float("nan")
    with pytest.raises(RecipeError, match=r"last.pt: optim: lr must be a finite number > 0, got nan"):
        recipe_from_dict(data, where="last.pt")
    assert recipe_from_dict(r.to_dict()) == r


# -- hostile recipe files and repeated settings (issue 27) ------------------------------------------


def test_a_key_given_twice_in_a_recipe_is_refused_naming_it_and_its_lines(tmp_path):
    p = tmp_path / "twice.yaml"
    p.write_text("base: ours\ntrain:\n  epochs: 2\n  batch: 4\n  epochs: 3\n")
    with pytest.raises(RecipeError) as e:
        load_recipe(p)
    assert str(e.value).startswith(f"{p}: ") and "duplicate key 'epochs' (lines 3 and 5)" in str(e.value)
    assert "\n" not in str(e.value)


def test_aliases_and_merge_keys_that_expand_little_are_still_read(tmp_path):
    p = tmp_path / "shared.yaml"
    p.write_text(
        "base: ours\n"
        "sizes:\n"
        "  cpu: &small {train.resolution: 64, train.batch: 2}\n"
        "  smoke:\n"
        "    <<: *small\n"
        "    train.batch: 1\n"  # a merge key's values may be overridden: that is what they are for
    )
    assert load_recipe(p, "cpu").train.batch == 2
    smoke = load_recipe(p, "smoke")
    assert (smoke.train.resolution, smoke.train.batch) == (64, 1)


def test_a_field_set_twice_on_the_command_line_is_refused():
    with pytest.raises(RecipeError, match=r"--set train.batch is given twice \('train.batch=2' and 'train.batch=4'\)"):
        parse_overrides(["train.batch=2", "loss.adv=0", "train.batch=4"])
    assert parse_overrides(["train.batch=2", "train.epochs=2"]) == {"train.batch": 2, "train.epochs": 2}


def test_a_recipe_that_is_not_utf8_is_one_line(tmp_path):
    p = tmp_path / "latin1.yaml"
    p.write_bytes("base: ours\ndescription: caf\xe9\n".encode("latin-1"))
    with pytest.raises(RecipeError, match=r"latin1.yaml: not UTF-8 text \(byte 0xe9 at offset 27\)"):
        load_recipe(p)


@pytest.mark.parametrize(
    "text, says",
    [
        ("base: ours\ngenerator: {name: ours, config: " + "{a: " * 3000 + "1" + "}" * 3001, "nested deeper than 100"),
        ("base: ours\ndescription: &d [x, *d]\n", "names a node that holds it"),
        (
            "base: ours\ndescription:\n  - &a0 [x, x, x, x, x, x, x, x, x]\n"
            + "".join(f"  - &a{i} [" + ", ".join([f"*a{i - 1}"] * 9) + "]\n" for i in range(1, 9)),
            "aliases expand the document to more than 100000 values",
        ),
    ],
    ids=["nested-3000-levels", "alias-to-itself", "alias-bomb-9-to-the-9"],
)
def test_deep_and_self_expanding_recipes_are_refused_before_anything_walks_them(tmp_path, text, says):
    """Each would end in a RecursionError or walk 9**9 values; a fresh process, killed at a
    bound, so that a regression fails the test instead of hanging the suite."""
    from conftest import run_cli

    p = tmp_path / "hostile.yaml"
    p.write_text(text)
    done = run_cli("recipes", str(p), timeout=120)
    assert done.returncode == 2, done.stderr
    assert done.stderr.strip().splitlines() == [done.stderr.strip()] and "Traceback" not in done.stderr
    assert f"{p}: not valid YAML: " in done.stderr and says in done.stderr
