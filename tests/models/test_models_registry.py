"""The registry: lazy discovery, close-name errors, duplicates, broken plugins, configs."""

from __future__ import annotations

import importlib
import subprocess
import sys
from dataclasses import dataclass

import pytest
import torch

import svbrdf_models as sm
from svbrdf_models import Registry


@dataclass
class FakeDist:
    name: str
    version: str = "1.0"


@dataclass
class FakeEntryPoint:
    """What importlib.metadata gives the registry: name, value, dist and load()."""

    name: str
    value: str
    dist: FakeDist

    def load(self):
        module, _, attr = self.value.partition(":")
        return getattr(importlib.import_module(module), attr)


BUILTIN = FakeDist("svbrdf-models")


def registry_with(attention=(), generators=(), discriminators=()) -> Registry:
    groups = {
        "svbrdf.attention": [
            FakeEntryPoint("multiscale", "svbrdf_models.networks.attention:MULTISCALE", BUILTIN),
            FakeEntryPoint("none", "svbrdf_models.networks.attention:NONE", BUILTIN),
            *attention,
        ],
        "svbrdf.generators": [FakeEntryPoint("ours", "svbrdf_models.networks.generators:OURS", BUILTIN), *generators],
        "svbrdf.discriminators": list(discriminators),
    }
    return Registry(lambda group: groups[group])


# -- discovery ---------------------------------------------------------------------------------


def test_builtins_are_registered_through_entry_points():
    from importlib.metadata import entry_points

    for kind, group in sm.KINDS.items():
        declared = {ep.name for ep in entry_points(group=group) if ep.dist.name == "svbrdf-models"}
        assert declared and declared <= set(sm.list_models(kind))
    assert {"ours", "unet", "no-attn"} <= set(sm.list_models("generator"))
    assert {"multiscale", "none", "se", "cbam"} <= set(sm.list_models("attention"))
    assert {"patchgan", "multi"} <= set(sm.list_models("discriminator"))


def test_list_filters_by_pattern():
    assert sm.list_models("attention", "c*") == ["cbam"]
    assert sm.list_models("generator", "nothing-like-this*") == []


def test_discovery_is_lazy():
    code = (
        "import sys, svbrdf_models as sm\n"
        "mods = lambda: sorted(m for m in sys.modules if m.startswith(('svbrdf_models.', 'svbrdf_example')))\n"
        "print(mods())\n"
        "sm.list_models('attention'); sm.list_models('generator')\n"
        "print(mods())\n"
        "sm.create_attention('se', 8)\n"
        "print(mods())\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    on_import, after_list, after_create = out.strip().splitlines()
    networks = ("svbrdf_models.networks.attention", "svbrdf_models.networks.generators", "svbrdf_models.networks.discriminators")
    assert not any(n in on_import for n in networks)
    assert not any(n in after_list for n in networks) and "svbrdf_example" not in after_list
    assert "svbrdf_models.networks.attention" in after_create and "svbrdf_models.networks.generators" not in after_create


def test_describe_gives_fields_defaults_and_source():
    info = sm.describe("attention", "multiscale")
    assert info.distribution == "svbrdf-models" and info.target.endswith(":MULTISCALE")
    (scales,) = info.fields
    assert scales.name == "scales" and scales.default == (1, 2, 4, 8) and scales.doc
    # A name's defaults override the class's: no-attn is ours with attention 'none'.
    fields = {f.name: f.default for f in sm.describe("generator", "no-attn").fields}
    assert fields["attention"] == "none" and fields["global_track"] is True
    fields = {f.name: f.default for f in sm.describe("generator", "unet").fields}
    assert fields["attention"] == "multiscale" and fields["global_track"] is False
    assert "Deschaintre" in sm.describe("generator", "no-attn").description
    assert "tiny" in sm.describe("generator", "ours").format()


# -- errors --------------------------------------------------------------------------------------


def test_unknown_name_suggests_lists_and_reminds_to_reinstall():
    with pytest.raises(sm.UnknownNameError) as e:
        sm.create_attention("multiscal", 8)
    msg = str(e.value)
    assert "'multiscale'" in msg and "Did you mean" in msg
    assert "cbam" in msg and "svbrdf-models" in msg
    assert "pip install -e" in msg


def test_unknown_name_lists_plugins_that_failed_to_load():
    broken = FakeEntryPoint("broken-gate", "svbrdf_no_such_module:GATE", FakeDist("svbrdf-broken-plugin"))
    reg = registry_with(attention=[broken])
    with pytest.raises(sm.UnknownNameError) as e:
        reg.create("attention", "gate", channels=8)
    msg = str(e.value)
    assert "broken-gate" in msg and "ModuleNotFoundError" in msg and "svbrdf_no_such_module" in msg
    assert "(from svbrdf-broken-plugin)" in msg
    # The healthy ones still work.
    assert reg.create("attention", "none", channels=8).out_channels == 8


def test_a_broken_plugin_names_itself_when_created():
    broken = FakeEntryPoint("broken-gate", "svbrdf_no_such_module:GATE", FakeDist("svbrdf-broken-plugin"))
    with pytest.raises(sm.PluginLoadError, match=r"broken-gate.*svbrdf-broken-plugin.*ModuleNotFoundError"):
        registry_with(attention=[broken]).create("attention", "broken-gate", channels=8)


def test_an_entry_point_must_name_a_spec_of_its_kind():
    not_spec = FakeEntryPoint("conv", "torch.nn:Conv2d", FakeDist("p"))
    wrong_kind = FakeEntryPoint("se-as-gen", "svbrdf_models.networks.attention:SE", FakeDist("p"))
    reg = registry_with(attention=[not_spec], generators=[wrong_kind])
    with pytest.raises(sm.PluginLoadError, match="expected a svbrdf_models.ModelSpec of kind 'attention'"):
        reg.create("attention", "conv", channels=8)
    with pytest.raises(sm.PluginLoadError, match="kind 'attention'.*expected.*kind 'generator'"):
        reg.create("generator", "se-as-gen")


def test_duplicate_name_is_an_error_naming_both_distributions():
    clash = FakeEntryPoint("multiscale", "svbrdf_models.networks.attention:SE", FakeDist("svbrdf-other-plugin"))
    reg = registry_with(attention=[clash])
    with pytest.raises(sm.DuplicateNameError) as e:
        reg.create("attention", "multiscale", channels=8)
    assert "svbrdf-models" in str(e.value) and "svbrdf-other-plugin" in str(e.value)
    assert reg.sources("attention", "multiscale") == ["svbrdf-models", "svbrdf-other-plugin"]
    # One distribution seen twice on sys.path is one registration, not a conflict.
    again = FakeEntryPoint("none", "svbrdf_models.networks.attention:NONE", BUILTIN)
    assert registry_with(attention=[again]).create("attention", "none", channels=4).out_channels == 4


def test_attention_plugin_without_out_channels_is_refused():
    reg = registry_with(
        attention=[FakeEntryPoint("bad", "test_models_registry:NO_OUT_CHANNELS", FakeDist("p"))]
    )
    with pytest.raises(sm.RegistryError, match="out_channels"):
        reg.create("attention", "bad", channels=8)


class _NoOutChannels(torch.nn.Module):
    def __init__(self, config, channels):
        super().__init__()

    def forward(self, x):
        return x


@dataclass(frozen=True)
class _EmptyConfig:
    pass


NO_OUT_CHANNELS = sm.ModelSpec("attention", _NoOutChannels, _EmptyConfig, "lacks out_channels")


def test_unknown_kind():
    with pytest.raises(sm.RegistryError, match="Did you mean 'generator'"):
        sm.list_models("generators")


# -- configs ---------------------------------------------------------------------------------


def test_config_errors_name_the_field_and_suggest():
    with pytest.raises(sm.ConfigError, match="'bas_channels'.*Did you mean 'base_channels'"):
        sm.create_generator("ours", {"bas_channels": 8})
    with pytest.raises(sm.ConfigError, match="'depth' expects int.*'four'"):
        sm.create_generator("ours", {"depth": "four"})
    with pytest.raises(sm.ConfigError, match="'depth' expects int"):
        sm.create_generator("ours", {"depth": True})
    with pytest.raises(sm.ConfigError, match="'norm' must be one of"):
        sm.create_discriminator("patchgan", {"norm": "group"})
    with pytest.raises(sm.ConfigError, match="2 names for 4 levels"):
        sm.create_generator("ours", {"preset": "tiny", "attention": ["se", "none"]})
    with pytest.raises(sm.RegistryError, match="unknown preset 'tiniest'.*Did you mean 'tiny'"):
        sm.create_generator("ours", preset="tiniest")
    with pytest.raises(sm.ConfigError, match="dropout must be in"):
        sm.create_generator("ours", {"dropout": 1.5})


def test_config_from_yaml_like_values():
    # YAML gives lists and ints where the dataclass wants tuples and floats.
    cfg = sm.resolve_config(
        "generator",
        "ours",
        {"preset": "tiny", "attention": ["se", "none", "cbam", "multiscale"], "dropout": 0},
    )
    assert cfg.attention == ("se", "none", "cbam", "multiscale") and cfg.dropout == 0.0 and cfg.depth == 4
    assert sm.config_to_dict(cfg)["base_channels"] == 8
    assert sm.resolve_config("attention", "multiscale", {"scales": [1, 3]}).scales == (1, 3)


def test_resolving_a_config_checks_the_modules_it_names():
    # Before, an unknown attention name or an attention_config the module does not take passed
    # resolve_config and failed while the U-Net was being built.
    with pytest.raises(sm.UnknownNameError, match="generator 'ours': field 'attention': unknown attention module 'cbma'.*'cbam'"):
        sm.resolve_config("generator", "ours", {"attention": "cbma"})
    with pytest.raises(sm.UnknownNameError, match="field 'attention': unknown attention module 'gate'"):
        sm.resolve_config("generator", "ours", {"preset": "tiny", "attention": ["se", "gate", "none", "se"]})
    with pytest.raises(sm.ConfigError, match="field 'attention_config': attention module 'cbam': unknown config field 'scales'"):
        sm.resolve_config("generator", "ours", {"attention": "cbam", "attention_config": {"scales": [1, 2]}})
    with pytest.raises(sm.ConfigError, match="field 'attention_config': attention module 'multiscale': scales must be"):
        sm.resolve_config("generator", "ours", {"attention_config": {"scales": [0]}})
    with pytest.raises(sm.ConfigError, match=r"init_std must be a finite number >= 0.*-0.5"):
        sm.resolve_config("discriminator", "patchgan", {"init_std": -0.5})
    # The same checks through a registry of plugins: a name only the full registry has is unknown here.
    with pytest.raises(sm.UnknownNameError, match="unknown attention module 'se'"):
        registry_with().resolve_config("generator", "ours", {"attention": "se"})


@pytest.mark.parametrize(
    "kind, name, config, size, fragment",
    [
        ("generator", "ours", {"preset": "tiny"}, 30, "multiples of 16 (2**depth, depth 4), got 30x30; the nearest sizes are 16 and 32"),
        ("generator", "ours", {}, 128, "multiples of 256 (2**depth, depth 8), got 128x128"),
        ("discriminator", "patchgan", {}, 16, "at least 24 (3 * 2**layers, layers 3), got 16x16"),
        ("discriminator", "multi", {"preset": "tiny"}, 8, "at least 12"),
    ],
)
def test_input_sizes_a_network_cannot_take_are_refused_before_it_is_built(kind, name, config, size, fragment):
    with pytest.raises(sm.ConfigError) as e:
        sm.check_input_size(kind, name, config, size)
    assert str(e.value).startswith(f"{kind} {name!r}: ") and fragment in str(e.value)


def test_input_sizes_that_work_pass_and_really_go_through():
    sm.check_input_size("generator", "ours", {"preset": "tiny"}, 32, 48)
    sm.check_input_size("discriminator", "patchgan", {"preset": "tiny", "renderings": 1}, 12)
    sm.check_input_size("generator", "mean", {}, 7)  # the baselines take any size
    g = sm.create_generator("ours", preset="tiny").eval()
    assert g(torch.rand(1, 3, 32, 48)).normal.shape[-2:] == (32, 48)
    d = sm.create_discriminator("patchgan", {"preset": "tiny", "renderings": 1})
    assert d(renderings=torch.rand(2, 1, 3, 12, 12))[0].numel() >= 2
    with pytest.raises(ValueError):  # one pixel less and the network itself fails
        d(renderings=torch.rand(2, 1, 3, 11, 11))
