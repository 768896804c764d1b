"""svbrdf-render: a standalone differentiable SVBRDF renderer.

Public API (everything importable from here)::

    from svbrdf_render import SVBRDF, Scene, Camera, PointLight, Flash, render, apply_image_effects
    from svbrdf_render import training_scene, evaluation_scene, fit_flash, refine_maps, refine_views
    from svbrdf_render import read_des18, write_des18, read_map_folder, write_map_folder
    from svbrdf_render import MetalRough, to_metal_rough, from_metal_rough, roundtrip_error

The core needs torch and numpy only; reading and writing image and YAML files needs the
``io`` extra (``pip install 'svbrdf-render[io]'``).
"""

from . import brdf
from .effects import DES18_EFFECTS, EFFECTS, PHOTO_EFFECTS, resolve_effects
from .errors import MapError, MapFileError, SceneError, SVBRDFError
from .formats.gltf import write_gltf
from .formats.mapfiles import (
    linear_to_srgb,
    read_des18,
    read_image,
    read_map_folder,
    read_png_encoding,
    srgb_to_linear,
    write_des18,
    write_exr,
    write_image,
    write_map_folder,
)
from .formats.materialx import validate_materialx, write_materialx
from .geometry import safe_normalize, surface_positions
from .maps import MAP_NAMES, SVBRDF, decode_normal, encode_normal, stored_value
from .metalrough import MetalRough, from_metal_rough, roundtrip_error, to_metal_rough
from .reference import render_reference
from .refinement.fit import FlashFit, fit_flash
from .refinement.refine import (
    DEFAULT_REFINE_STEPS,
    MIN_REFINE_SIDE,
    Refinement,
    RefineSettings,
    refine_maps,
    refine_start,
)
from .refinement.views import ViewsRefinement, refine_views
from .renderer import BACKENDS, RenderPlan, apply_image_effects, build_plan, log_radiance, place_scene, render
from .sampling import EVAL_CONFIGS, EVAL_SEED, evaluation_scene, training_scene
from .scene import DES18_DISTANCE, Camera, Flash, PointLight, Scene
from .stages import SceneGeometry
from .tiling import MIN_TILEABLE_SIDE, make_tileable, make_tileable_map, seam_error
from .viewer import VIEWER_INTENSITY, viewer_scene, write_viewer

#: The package's version, its one source: pyproject.toml reads it (setuptools dynamic version).
__version__ = "0.2.0"

__all__ = [
    "BACKENDS",
    "DEFAULT_REFINE_STEPS",
    "MIN_REFINE_SIDE",
    "RefineSettings",
    "Refinement",
    "refine_maps",
    "refine_start",
    "ViewsRefinement",
    "refine_views",
    "DES18_DISTANCE",
    "DES18_EFFECTS",
    "EFFECTS",
    "EVAL_CONFIGS",
    "EVAL_SEED",
    "MAP_NAMES",
    "encode_normal",
    "decode_normal",
    "stored_value",
    "PHOTO_EFFECTS",
    "SVBRDF",
    "Camera",
    "Flash",
    "FlashFit",
    "MapError",
    "MapFileError",
    "MetalRough",
    "MIN_TILEABLE_SIDE",
    "PointLight",
    "SVBRDFError",
    "Scene",
    "SceneError",
    "apply_image_effects",
    "brdf",
    "build_plan",
    "place_scene",
    "RenderPlan",
    "SceneGeometry",
    "evaluation_scene",
    "fit_flash",
    "from_metal_rough",
    "log_radiance",
    "read_des18",
    "read_image",
    "read_map_folder",
    "render",
    "render_reference",
    "resolve_effects",
    "roundtrip_error",
    "safe_normalize",
    "srgb_to_linear",
    "linear_to_srgb",
    "surface_positions",
    "to_metal_rough",
    "training_scene",
    "write_des18",
    "write_image",
    "write_exr",
    "read_png_encoding",
    "write_map_folder",
    "write_gltf",
    "write_materialx",
    "validate_materialx",
    "make_tileable",
    "make_tileable_map",
    "seam_error",
    "VIEWER_INTENSITY",
    "viewer_scene",
    "write_viewer",
]

# Modules that moved into subpackages (issues 38 and 48): the old names import the new modules
# with a DeprecationWarning until release _MOVED_UNTIL (svbrdf_render.plumbing.moved; CHANGELOG.md). A
# module split in several (files, materialfiles) names the subpackage that states their names.
#: The release that removes the old names below (0.2.0 keeps them, with a warning).
_MOVED_UNTIL = "0.3.0"
_MOVED = {
    "svbrdf_render.refine": "svbrdf_render.refinement.refine",
    "svbrdf_render.fit": "svbrdf_render.refinement.fit",
    "svbrdf_render.files": "svbrdf_render.plumbing",
    "svbrdf_render.formats.files": "svbrdf_render.plumbing",
    "svbrdf_render.machine": "svbrdf_render.plumbing.machine",
    "svbrdf_render.moved": "svbrdf_render.plumbing.moved",
    "svbrdf_render.mapfiles": "svbrdf_render.formats.mapfiles",
    "svbrdf_render.materialfiles": "svbrdf_render.formats",
    "svbrdf_render.formats.materialfiles": "svbrdf_render.formats",
    "svbrdf_render.yamlio": "svbrdf_render.formats.yamlio",
}

from .plumbing.moved import install as _install_moved

_install_moved(_MOVED, _MOVED_UNTIL)
