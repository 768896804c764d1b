#!/usr/bin/env python
"""Does a material folder look the same in Blender as in its relit preview? A headless check.

``svbrdf-models predict`` writes, per photo, a folder of maps, a ``material.gltf`` that an artist
opens in Blender, and ``relit.gif``, the maps rendered by this project's renderer under a point
light circling the patch. This benchmark opens ``material.gltf`` with the glTF importer that
ships with Blender, renders it with Cycles under the same camera and the same light as a few
frames of the preview, and compares the two images.

What it does, per folder (``blender -b --factory-startup --python <script>``; the script is
:data:`BLENDER_SCRIPT`, written beside the results):

1. Import ``material.gltf`` and report what the importer built: the shader that feeds the
   material output, and for its Base Color, Metallic, Roughness and Normal inputs the chain of
   nodes back to an image, with each image's file and colour space. The check passes when the
   shader is a Principled BSDF, Base Color reads the glTF's base colour image as ``sRGB``,
   Metallic and Roughness read the blue and green channels of its metallic/roughness image as
   ``Non-Color``, and Normal goes through a tangent-space Normal Map node from its normal
   image read as ``Non-Color``. Any other finding is printed and the exit status is 1.
2. Scene. glTF is +Y up and Blender +Z up: the importer maps glTF ``(x, y, z)`` to Blender
   ``(x, -z, y)``, so the patch arrives standing up. The check turns it back (-90 degrees about
   X) so it lies in Blender's ``z = 0`` facing +Z with the image's top towards +Y, exactly the
   project's scene (the patch ``[-1, 1]^2``), and verifies the corners and texture coordinates.
   Camera and lights then take the project's coordinates unchanged.
3. Camera. The project's renderer shades each pixel centre of the patch with a view vector
   towards a *point* camera at ``(0, 0, DES18_DISTANCE)`` (2.2): a perspective pinhole. A
   perspective camera there, looking down -Z, with a full field of view of
   ``2 atan(1 / 2.2)`` = 48.90 degrees (``svbrdf_render.Camera``'s default) frames ``[-1, 1]^2``
   exactly, and a plane facing the camera maps affinely to the image, so its pixel centres
   land on the project's. Cycles' pixel filter is narrowed to 0.01 px so that every sample
   hits the pixel centre, as the project's renderer does (the default 1.5 px Blackman-Harris
   filter would blur Blender's image by about a pixel).
4. Light. The preview's frame ``k`` of 24 puts a point light of intensity 1 at
   ``(1.5 cos a, 1.5 sin a, 1.6)``, ``a = 2 pi k / 24``. The project's radiance is
   ``I f cos / d^2`` (``f`` the BRDF): ``I`` is a radiant intensity (W/sr). Cycles gives a
   point light of power ``P`` watts a radiant intensity ``P / (4 pi)``, spread evenly over
   the sphere. So ``P = 4 pi I``: 12.566 W for the preview's ``I = 1``. Radius 0 (a true
   point), world black, no bounces (the project renders direct light only), light threshold 0.
   The conversion is not taken on trust: each run also renders the patch with a plain grey
   Diffuse BSDF (albedo 0.5, Lambertian) under the preview's light at 30 degrees and compares
   it with the project's Lambertian ``0.5 / pi * I cos / d^2``: the ratio of their means and
   the RMSE relative to the mean ("calibration"; 1 and 0% when camera, framing, orientation
   and light power all match, whatever the material).
5. Render with Cycles on the CPU at the preview's size (the maps' side, at most 256 px, as
   the preview), a few samples, denoising and adaptive sampling off, to linear 32-bit
   OpenEXR (view transform Standard, exposure 0: colour management does not touch the EXR).
6. Compare. The project's frames are ``svbrdf_render.render`` of the folder's maps (read with
   ``svbrdf_render.read_map_folder``: the project's own diffuse/specular/roughness/normal
   maps, which the preview renders) under the same scene. Both are exposed with the
   preview's gain (all 24 frames scaled so their brightest 1% reaches 0.9; the project's
   frames are checked equal to ``svbrdf_models.capture.one.relight_frames``), clipped to [0, 1]
   and sRGB-encoded: display values, as the GIF shows them. Figures per light: RMSE of
   display values against the preview; RMSE against the project's renderer fed the glTF maps
   themselves (base colour + metallic converted back with ``svbrdf_render.from_metal_rough``),
   which separates what Blender's BSDF does differently from what the metal/rough conversion
   loses; and Blender's mean linear brightness over the preview's and over the glTF maps'.

Expected differences: Blender's Principled BSDF is not the project's BRDF. Blender 3.x's
(v1) adds a Burley diffuse (Disney's, with a little retro-reflection) to the specular lobe with
no ``1 - F`` weighting, so a grey dielectric renders about 4% brighter than the des18 maps
(measured: 1.038 to 1.043 for constant grey maps, 1.015 for a grey metal); its Fresnel (the
dielectric one, interpolated towards the base colour for metals) and its masking are its own,
and its ``alpha`` is ``r^2`` where the project's is ``0.001 + 0.999 r^2``. Blender 4.x's
Principled BSDF differs again (multiple-scattering GGX by default, energy-conserving layers;
not run here). And metal/rough has one colour where the project has two: a coloured specular
on a dielectric cannot survive the conversion (``svbrdf_render/metalrough.py``).

Usage::

    .venv/bin/python benchmarks/blender_check.py MATERIAL_FOLDER [MATERIAL_FOLDER ...]
    .venv/bin/python benchmarks/blender_check.py maps/photo1 --frames 0,3,6,9 --samples 8 -o out

A material folder is what ``svbrdf-models predict PHOTO -o OUT`` writes as ``OUT/<photo>/``.
Writes, in ``-o`` (default ``blender-check``): ``<name>.png`` (rows: project renderer,
Blender Cycles, ``|difference|`` heat map; one column per light), ``<name>/`` (Blender's EXR
frames, the generated script, its job file and log, the importer's report) and
``blender_check.md`` (the tables). Needs Blender 3.4 or later with NumPy in its Python (its glTF
importer imports NumPy; Debian: ``apt-get install blender python3-numpy``). Blender 3.4's
importer uses ``numpy.bool``, which NumPy 1.24 removed; the script restores the alias before
importing (fixed upstream in Blender 3.5). No test depends on Blender.

Exit status: 0 every folder imported as expected; 1 an importer finding differs from the
expected one, or Blender failed (one line, and the log's path); 2 a folder is missing, is not a
material folder, or no Blender is found (one line on stderr, nothing run).
"""

from __future__ import annotations

import argparse
import io
import json
import math
import shutil
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import torch

PROG = "blender_check"
#: The relit preview's light circle (``svbrdf_models.capture.one.relight_frames``' defaults).
RELIT_RADIUS, RELIT_HEIGHT = 1.5, 1.6
#: Albedo of the grey Lambertian patch that calibrates Blender's light against the project's.
CALIBRATION_ALBEDO = 0.5
#: The preview frame that lights the calibration: at 30 degrees its light breaks every mirror
#: symmetry of the square, so a flipped, turned or transposed image would show.
CALIBRATION_FRAME = 2

# The script Blender runs. Plain Python for Blender's own interpreter (bpy, NumPy); its one
# argument after "--" is the job file (JSON) that this benchmark writes.
BLENDER_SCRIPT = r'''"""Written by benchmarks/blender_check.py: import a material.gltf, report what the
importer built, and render it with Cycles under the project's camera and lights."""
import json
import math
import os
import sys

import bpy
import numpy

with open(sys.argv[sys.argv.index("--") + 1]) as f:
    job = json.load(f)
if not hasattr(numpy, "bool"):  # Blender 3.4's glTF importer uses numpy.bool (removed in NumPy 1.24)
    numpy.bool = bool

bpy.ops.wm.read_factory_settings(use_empty=True)
bpy.ops.import_scene.gltf(filepath=job["gltf"])
scene = bpy.context.scene
meshes = [o for o in scene.objects if o.type == "MESH"]
report = {"blender": bpy.app.version_string, "meshes": len(meshes)}
try:
    import io_scene_gltf2
    report["importer"] = ".".join(str(v) for v in io_scene_gltf2.bl_info["version"])
except Exception:  # the version is for the report only
    report["importer"] = "?"
obj = meshes[0]

# -- the patch back into the project's frame: z = 0, facing +Z, image top at +Y --------------
obj.rotation_mode = "XYZ"
obj.rotation_euler = (-math.pi / 2, 0.0, 0.0)
bpy.context.view_layer.update()
mesh = obj.data
uv = mesh.uv_layers.active.data
report["corners"] = [
    {"uv": list(uv[loop.index].uv), "xyz": list(obj.matrix_world @ mesh.vertices[loop.vertex_index].co)}
    for loop in mesh.loops
]
report["face_normal"] = list((obj.matrix_world.to_3x3() @ mesh.polygons[0].normal).normalized())

# -- what the importer built -------------------------------------------------------------------


def describe(node):
    d = {"node": node.bl_idname}
    if node.bl_idname == "ShaderNodeTexImage" and node.image is not None:
        d.update(image=os.path.basename(bpy.path.abspath(node.image.filepath)),
                 colorspace=node.image.colorspace_settings.name,
                 interpolation=node.interpolation, size=list(node.image.size))
    if node.bl_idname == "ShaderNodeNormalMap":
        d.update(space=node.space, strength=node.inputs["Strength"].default_value)
    if hasattr(node, "mode") and node.bl_idname.startswith("ShaderNodeSeparate"):
        d["mode"] = node.mode
    return d


def chain(socket):
    """The nodes feeding ``socket``, nearest first, following each node's first linked input."""
    out = []
    while socket.is_linked:
        link = socket.links[0]
        d = describe(link.from_node)
        d["output"] = link.from_socket.name
        out.append(d)
        linked = [s for s in link.from_node.inputs if s.is_linked]
        if not linked:
            break
        socket = linked[0]
    return out


material = obj.material_slots[0].material if obj.material_slots else None
report["material"] = material.name if material else None
if material is not None and material.use_nodes:
    tree = material.node_tree
    outputs = [n for n in tree.nodes if n.bl_idname == "ShaderNodeOutputMaterial"]
    output = next((n for n in outputs if n.is_active_output), outputs[0] if outputs else None)
    surface = output.inputs["Surface"] if output else None
    shader = surface.links[0].from_node if surface and surface.is_linked else None
    report["shader"] = shader.bl_idname if shader else None
    if shader is not None and shader.bl_idname == "ShaderNodeBsdfPrincipled":
        report["distribution"] = shader.distribution
        report["inputs"] = {name: chain(shader.inputs[name])
                            for name in ("Base Color", "Metallic", "Roughness", "Normal")}
        constants = {}
        for s in shader.inputs:
            if not s.is_linked and hasattr(s, "default_value") and s.name not in report["inputs"]:
                v = s.default_value
                constants[s.name] = round(v, 4) if isinstance(v, float) else [round(x, 4) for x in v]
        report["constants"] = constants
with open(job["report"], "w") as f:
    json.dump(report, f, indent=1)

# -- scene: camera, light, world, Cycles ----------------------------------------------------------
scene.render.engine = "CYCLES"
cycles = scene.cycles
cycles.device = "CPU"
cycles.samples = job["samples"]
cycles.use_adaptive_sampling = False
cycles.use_denoising = False
cycles.max_bounces = 0  # direct light only, as the project renders
cycles.filter_width = 0.01  # every sample at the pixel centre, as the project shades
cycles.light_sampling_threshold = 0.0
cycles.seed = 0
scene.render.threads_mode = "FIXED"
scene.render.threads = job["threads"]
scene.render.resolution_x = scene.render.resolution_y = job["size"]
scene.render.resolution_percentage = 100
scene.render.pixel_aspect_x = scene.render.pixel_aspect_y = 1.0
scene.render.film_transparent = False
scene.view_settings.view_transform = "Standard"
scene.view_settings.look = "None"
scene.view_settings.exposure = 0.0
scene.view_settings.gamma = 1.0
scene.render.image_settings.file_format = "OPEN_EXR"
scene.render.image_settings.color_depth = "32"
scene.render.image_settings.exr_codec = "ZIP"
world = bpy.data.worlds.new("black")
world.color = (0.0, 0.0, 0.0)
scene.world = world

camera = bpy.data.cameras.new("camera")
camera.type = "PERSP"
camera.sensor_fit = "AUTO"  # square image: the angle is both the horizontal and vertical view
camera.angle = math.radians(job["fov"])
camera.clip_start, camera.clip_end = 0.01, 100.0
camera_obj = bpy.data.objects.new("camera", camera)
camera_obj.location = job["camera"]
camera_obj.rotation_euler = (0.0, 0.0, 0.0)  # looks down -Z, image up = +Y
scene.collection.objects.link(camera_obj)
scene.camera = camera_obj

light = bpy.data.lights.new("light", "POINT")
light.energy = job["power"]
light.color = (1.0, 1.0, 1.0)
light.shadow_soft_size = 0.0
if hasattr(light, "use_soft_falloff"):  # Blender 4.x: no softening near the light
    light.use_soft_falloff = False
light_obj = bpy.data.objects.new("light", light)
scene.collection.objects.link(light_obj)


def render_to(position, stem):
    light_obj.location = position
    exr = os.path.join(job["out"], stem + ".exr")
    scene.render.filepath = exr
    bpy.ops.render.render(write_still=True)
    image = bpy.data.images.load(exr)
    w, h = image.size
    pixels = numpy.empty(w * h * 4, dtype=numpy.float32)
    image.pixels.foreach_get(pixels)
    # Blender's rows run bottom to top: flip to the project's top-to-bottom order
    rgb = pixels.reshape(h, w, 4)[::-1, :, :3].copy()
    numpy.save(os.path.join(job["out"], stem + ".npy"), rgb)
    bpy.data.images.remove(image)


for stem, position in job["lights"]:
    render_to(position, stem)

grey = bpy.data.materials.new("calibration")
grey.use_nodes = True
nodes = grey.node_tree.nodes
for n in list(nodes):
    nodes.remove(n)
lambert = nodes.new("ShaderNodeBsdfDiffuse")
lambert.inputs["Color"].default_value = (job["albedo"],) * 3 + (1.0,)
lambert.inputs["Roughness"].default_value = 0.0  # Lambertian
out = nodes.new("ShaderNodeOutputMaterial")
grey.node_tree.links.new(lambert.outputs["BSDF"], out.inputs["Surface"])
if obj.material_slots:
    obj.material_slots[0].material = grey
else:
    obj.data.materials.append(grey)
render_to(job["calibration_light"], "calibration")
'''


# -- the project's side ----------------------------------------------------------------------------


def light_positions(n: int = 24) -> torch.Tensor:
    """``(n, 3)``: the relit preview's light positions (``svbrdf_models.capture.one._relight_raw``)."""
    angles = torch.arange(n, dtype=torch.float32) * (2 * math.pi / n)
    return torch.stack(
        [RELIT_RADIUS * angles.cos(), RELIT_RADIUS * angles.sin(), torch.full_like(angles, RELIT_HEIGHT)], -1
    )


def preview_scene(positions: torch.Tensor, effects=None):
    """The preview's scene: on-axis camera at the Des18 distance, a point light of intensity 1
    at each of ``positions`` ``(K, 3)``."""
    from svbrdf_render import DES18_DISTANCE, DES18_EFFECTS, Camera, PointLight, Scene

    camera = Camera(torch.tensor([0.0, 0.0, DES18_DISTANCE]))
    return Scene(camera, (PointLight(positions, 1.0),), DES18_EFFECTS if effects is None else effects)


def preview_gain(raw: torch.Tensor) -> float:
    """The preview's exposure: the gain that brings the brightest 1% of its frames to 0.9
    (``svbrdf_models.capture.one``; checked against ``relight_frames`` by :func:`project_frames`)."""
    sample = raw.flatten()[:: max(1, raw.numel() // 1_000_000)]
    top = float(torch.quantile(sample, 0.99))
    return 0.9 / top if top > 0 else 1.0


def display(linear: torch.Tensor, gain: float) -> torch.Tensor:
    """Display values, as the preview shows them: exposed, clipped, sRGB-encoded."""
    from svbrdf_render import linear_to_srgb

    return linear_to_srgb((linear * gain).nan_to_num(0.0).clamp(0, 1))


def gltf_maps(folder: Path, gltf: dict, normal: torch.Tensor):
    """The maps as the glTF hands them to Blender (base colour, metallic, roughness), brought
    back to the project's convention, with the folder's normals."""
    from svbrdf_render import MetalRough, from_metal_rough, read_image, srgb_to_linear

    images = expected_images(gltf)
    base = srgb_to_linear(read_image(folder / images["basecolor"], channels=3))
    packed = read_image(folder / images["metallic_roughness"], channels=3)
    size = normal.shape[-2:]
    if base.shape[-2:] != size:  # the preview's side is smaller than the maps'
        import torch.nn.functional as F

        base, packed = (F.interpolate(t[None], size=tuple(size), mode="area")[0]
                        for t in (base, packed))
    return from_metal_rough(MetalRough(base[None], packed[None, 2:3], packed[None, 1:2], normal))


@dataclass
class Project:
    """The project's renderings of one folder at the preview's size."""

    frames: torch.Tensor  # (24, 3, S, S) linear, intensity 1
    gain: float
    preview_match: float  # max |frames exposed - relight_frames(maps)|
    gltf_frames: torch.Tensor  # (24, 3, S, S): the glTF's maps in the project's renderer


def project_frames(folder: Path, gltf: dict) -> Project:
    from svbrdf_models.capture.relight import RELIT_FRAMES, RELIT_SIZE, relight_frames
    from svbrdf_render import read_map_folder, render

    maps = read_map_folder(folder)
    side = min(RELIT_SIZE, max(maps.size))
    if tuple(maps.size) != (side, side):
        maps = maps.resize(side)
    scene = preview_scene(light_positions(RELIT_FRAMES))
    with torch.no_grad():
        raw = render(maps, scene)[0]
        gain = preview_gain(raw)
        match = float(((raw * gain).clamp(0, 1) - relight_frames(maps)).abs().max())
        gltf_raw = render(gltf_maps(folder, gltf, maps.normal), scene)[0]
    return Project(raw, gain, match, gltf_raw)


def lambert_frame(size: int, position: torch.Tensor) -> torch.Tensor:
    """``(3, S, S)``: the project's grey Lambertian patch under one light (the calibration)."""
    from svbrdf_render import SVBRDF, render

    flat = SVBRDF.constant(1, size)
    grey = SVBRDF(
        flat.normal,
        torch.full_like(flat.diffuse, CALIBRATION_ALBEDO),
        torch.ones_like(flat.roughness),
        torch.zeros_like(flat.specular),
    )
    with torch.no_grad():
        return render(grey, preview_scene(position, ("diffuse", "cosine", "falloff")))[0]


# -- the importer's report -------------------------------------------------------------------------


def expected_images(gltf: dict) -> dict[str, str]:
    """File names of the glTF's base colour, metallic/roughness and normal images."""
    from urllib.parse import unquote

    material = gltf["materials"][0]
    pbr = material.get("pbrMetallicRoughness", {})

    def image(ref):
        if ref is None:
            return None
        return Path(unquote(gltf["images"][gltf["textures"][ref["index"]]["source"]]["uri"])).name

    return {
        "basecolor": image(pbr.get("baseColorTexture")),
        "metallic_roughness": image(pbr.get("metallicRoughnessTexture")),
        "normal": image(material.get("normalTexture")),
    }


def judge_report(report: dict, gltf: dict) -> list[str]:
    """What differs from the expected import (empty: all as expected)."""
    problems = []
    for c in report.get("corners", []):
        (u, v), (x, y, z) = c["uv"], c["xyz"]
        if max(abs(x - (2 * u - 1)), abs(y - (2 * v - 1)), abs(z)) > 1e-5:
            problems.append(
                f"corner uv {u:.0f},{v:.0f} at {x:+.3f},{y:+.3f},{z:+.3f}: not the project's patch, image up"
            )
    if report.get("face_normal") and report["face_normal"][2] < 0.9999:
        problems.append(f"the patch faces {report['face_normal']}, not +Z")
    if report.get("shader") != "ShaderNodeBsdfPrincipled":
        return problems + [f"the material output is fed by {report.get('shader')}, not a Principled BSDF"]
    want = expected_images(gltf)
    inputs = report["inputs"]

    def expect(name, steps):
        got = inputs.get(name, [])
        shown = " <- ".join(_step(s) for s in got) or "nothing"
        if len(got) != len(steps):
            problems.append(f"{name} <- {shown}")
            return
        for s, (node, output, extra) in zip(got, steps):
            if s["node"] not in node or (output and s["output"] not in output) or any(
                s.get(k) != v for k, v in extra.items()
            ):
                problems.append(f"{name} <- {shown}")
                return

    image = ("ShaderNodeTexImage",)
    separate = ("ShaderNodeSeparateColor", "ShaderNodeSeparateRGB")
    expect("Base Color", [(image, ("Color",), {"image": want["basecolor"], "colorspace": "sRGB"})])
    for name, channel in (("Metallic", ("Blue", "B")), ("Roughness", ("Green", "G"))):
        expect(name, [(separate, channel, {}),
                      (image, ("Color",), {"image": want["metallic_roughness"], "colorspace": "Non-Color"})])
    expect("Normal", [(("ShaderNodeNormalMap",), ("Normal",), {"space": "TANGENT", "strength": 1.0}),
                      (image, ("Color",), {"image": want["normal"], "colorspace": "Non-Color"})])
    return problems


def _step(s: dict) -> str:
    name = s["node"].removeprefix("ShaderNode")
    if "image" in s:
        return f"{name}({s['image']}, {s['colorspace']}).{s['output']}"
    if "space" in s:
        return f"{name}({s['space']}, strength {s['strength']:g}).{s['output']}"
    return f"{name}.{s['output']}"


def describe_report(report: dict) -> list[str]:
    lines = [f"Blender {report['blender']}, glTF importer {report.get('importer')}: "
             f"{(report.get('shader') or 'no shader').removeprefix('ShaderNode')} "
             f"(distribution {report.get('distribution', '?')})"]
    for name, steps in report.get("inputs", {}).items():
        lines.append(f"  {name} <- " + " <- ".join(_step(s) for s in steps))
    const = report.get("constants", {})
    shown = {k: const[k] for k in ("Specular", "Specular Tint", "IOR", "Sheen", "Clearcoat", "Subsurface",
                                   "Transmission", "Specular IOR Level", "Coat Weight") if k in const}
    if shown:
        lines.append("  constants: " + ", ".join(f"{k} {v}" for k, v in shown.items()))
    return lines


# -- one folder ----------------------------------------------------------------------------------


@dataclass
class Result:
    """What the check found for one folder: the import, and per light the comparison."""

    name: str
    findings: list[str]
    problems: list[str]
    rows: list[dict] = field(default_factory=list)
    calibration: float = float("nan")
    calibration_rmse: float = float("nan")
    rerender_rmse: float | None = None
    seconds: float = 0.0
    blender_seconds: float = 0.0
    preview_match: float = float("nan")


class BlenderFailed(Exception):
    """Blender did not finish the job; the message says why in one line and names the log."""


def run_blender(blender: str, job: dict, work: Path, timeout: float) -> float:
    script, job_file, log = work / "blender_script.py", work / "job.json", work / "blender.log"
    for stale in [*work.glob("*.npy"), *work.glob("*.exr"), work / "import_report.json"]:
        stale.unlink(missing_ok=True)  # a failed run must not pass on an earlier run's files
    script.write_text(BLENDER_SCRIPT)
    job_file.write_text(json.dumps(job, indent=1))
    cmd = [blender, "-b", "--factory-startup", "--python-exit-code", "1", "--python", str(script),
           "--", str(job_file)]
    t = time.perf_counter()
    try:
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout)
    except subprocess.TimeoutExpired as e:
        out = e.stdout or b""  # bytes whatever text= says
        log.write_text(out.decode(errors="replace") if isinstance(out, bytes) else out)
        raise BlenderFailed(f"Blender ran past --timeout {timeout:g} s; log: {log}") from None
    seconds = time.perf_counter() - t
    log.write_text(proc.stdout + proc.stderr)
    missing = [s for s, _ in job["lights"] if not (work / f"{s}.npy").is_file()]
    outputs = [work / "import_report.json", work / "calibration.npy"]
    if proc.returncode != 0 or missing or not all(p.is_file() for p in outputs):
        text = proc.stdout + proc.stderr
        if "No module named 'numpy'" in text:
            why = ("Blender's Python has no NumPy, which its glTF importer needs "
                   "(Debian: apt-get install python3-numpy)")
        else:
            errors = [ln for ln in text.splitlines() if "Error" in ln]
            why = errors[-1].strip() if errors else f"exit status {proc.returncode}"
        raise BlenderFailed(f"Blender failed: {why}; log: {log}")
    return seconds


def rmse(a: torch.Tensor, b: torch.Tensor) -> float:
    """Root mean square of ``a - b`` over every pixel and channel."""
    return float(((a - b) ** 2).mean().sqrt())


def check_one(folder: Path, out: Path, args, frames: list[int]) -> Result:
    from svbrdf_render import DES18_DISTANCE, Camera

    t0 = time.perf_counter()
    gltf = json.loads((folder / "material.gltf").read_text())
    project = project_frames(folder, gltf)
    side = project.frames.shape[-1]
    positions = light_positions(project.frames.shape[0])
    work = out / folder.name
    work.mkdir(parents=True, exist_ok=True)
    job = {
        "gltf": str((folder / "material.gltf").resolve()),
        "out": str(work.resolve()),
        "report": str((work / "import_report.json").resolve()),
        "size": side,
        "samples": args.samples,
        "threads": args.threads,
        "fov": Camera().fov,
        "camera": [0.0, 0.0, DES18_DISTANCE],
        "power": 4 * math.pi * 1.0,  # W: radiant intensity 1 W/sr (the preview's I = 1) = P / (4 pi)
        "albedo": CALIBRATION_ALBEDO,
        "lights": [[f"light{k:02d}", positions[k].tolist()] for k in frames],
        "calibration_light": positions[CALIBRATION_FRAME].tolist(),
    }
    blender_seconds = run_blender(args.blender_path, job, work, args.timeout)
    report = json.loads((work / "import_report.json").read_text())
    result = Result(folder.name, describe_report(report), judge_report(report, gltf))
    result.blender_seconds = blender_seconds
    result.preview_match = project.preview_match
    record = folder / "material.json"
    if record.is_file():
        result.rerender_rmse = json.loads(record.read_text()).get("rerender_rmse")

    import numpy as np

    def load(stem):
        return torch.from_numpy(np.load(work / f"{stem}.npy")).permute(2, 0, 1).float()

    lambert = lambert_frame(side, positions[CALIBRATION_FRAME])
    calib = load("calibration")
    result.calibration = float(calib.mean() / lambert.mean())
    result.calibration_rmse = rmse(calib, lambert) / float(lambert.mean())
    pictures = []
    for k in frames:
        blender = load(f"light{k:02d}")
        mine, gltf_mine = project.frames[k], project.gltf_frames[k]
        shown = [display(x, project.gain) for x in (mine, blender, gltf_mine)]
        result.rows.append({
            "frame": k,
            "degrees": round(360 * k / project.frames.shape[0]),
            "rmse": rmse(shown[1], shown[0]),
            "rmse_gltf": rmse(shown[1], shown[2]),
            "rmse_conversion": rmse(shown[2], shown[0]),
            "brightness": float(blender.mean() / mine.mean()),
            "brightness_gltf": float(blender.mean() / gltf_mine.mean()),
        })
        pictures.append((shown[0], shown[1]))
    figure(result, pictures, out / f"{folder.name}.png", args.heat_max)
    result.seconds = time.perf_counter() - t0
    return result


def figure(result: Result, pictures, path: Path, heat_max: float) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    k = len(pictures)
    side = max(pictures[0][0].shape[-1], 128) / 100  # inches: one image pixel per figure pixel at 100 dpi
    fig, axes = plt.subplots(3, k, figsize=(side * k + 1.3, side * 3 + 0.9), squeeze=False)
    heat = None
    for j, ((mine, blender), row) in enumerate(zip(pictures, result.rows)):
        diff = (blender - mine).abs().mean(0)
        images = [mine.permute(1, 2, 0).numpy(), blender.permute(1, 2, 0).numpy(), diff.numpy()]
        for i, im in enumerate(images):
            ax = axes[i][j]
            if i < 2:
                ax.imshow(im, interpolation="nearest")
            else:
                heat = ax.imshow(im, cmap="magma", vmin=0, vmax=heat_max, interpolation="nearest")
            ax.set_xticks([])
            ax.set_yticks([])
        axes[0][j].set_title(f"light at {row['degrees']}°", fontsize=7)
        axes[2][j].set_xlabel(f"RMSE {row['rmse']:.3f}", fontsize=7)
    for i, label in enumerate(("project renderer\n(relit preview)", "Blender Cycles\n(material.gltf)",
                               "|difference|\n(display values)")):
        axes[i][0].set_ylabel(label, fontsize=7)
    fig.suptitle(result.name, fontsize=7)
    fig.tight_layout(rect=(0, 0, 0.92, 0.97), pad=0.3, h_pad=0.2, w_pad=0.2)
    cax = fig.add_axes((0.93, 0.06, 0.015, 0.25))
    fig.colorbar(heat, cax=cax).ax.tick_params(labelsize=6)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=100)
    plt.close(fig)
    from PIL import Image

    # 256 colours, dithered: under half the size of the full-colour figure (these textures
    # hardly compress), small enough to keep in a repository; the tables come from the EXRs.
    with Image.open(buf) as im:
        rgb = im.convert("RGB")
        palette = rgb.quantize(256, method=Image.Quantize.MEDIANCUT)
        rgb.quantize(palette=palette, dither=Image.Dither.FLOYDSTEINBERG).save(path, optimize=True)


# -- report ----------------------------------------------------------------------------------------


def table(results: list[Result], args) -> str:
    lines = [
        "## Blender check: material.gltf in Blender Cycles against the relit preview",
        "",
        f"Samples {args.samples}, Cycles threads {args.threads}; point light P = 4 pi W per "
        "unit of the preview's intensity; RMSE of display values (preview exposure, clipped, sRGB).",
        "",
        "| material | light | RMSE vs preview | RMSE vs glTF maps, project renderer | "
        "RMSE conversion alone | brightness Blender / preview | Blender / glTF maps |",
        "|---|---:|---:|---:|---:|---:|---:|",
    ]
    for r in results:
        for row in r.rows:
            lines.append(
                f"| {r.name} | {row['degrees']}° | {row['rmse']:.4f} | {row['rmse_gltf']:.4f} | "
                f"{row['rmse_conversion']:.4f} | {row['brightness']:.3f} | "
                f"{row['brightness_gltf']:.3f} |"
            )
    lines += ["", "| material | import | calibration (Blender / Lambert) | mean RMSE vs preview "
              "| photo re-rendering RMSE | seconds (Blender) |", "|---|---|---:|---:|---:|---:|"]
    for r in results:
        mean = sum(row["rmse"] for row in r.rows) / len(r.rows)
        rerender = f"{r.rerender_rmse:.4f}" if r.rerender_rmse is not None else "-"
        lines.append(
            f"| {r.name} | {'as expected' if not r.problems else 'DIFFERS'} | {r.calibration:.4f} "
            f"(RMSE {r.calibration_rmse:.1%}) | {mean:.4f} | {rerender} | {r.seconds:.1f} "
            f"({r.blender_seconds:.1f}) |"
        )
    lines.append("")
    for r in results:
        lines += [f"**{r.name}**", "", "```", *r.findings]
        lines += [f"DIFFERS: {p}" for p in r.problems] or ["import: as expected"]
        lines += [f"project frames = relight_frames: max |diff| {r.preview_match:.1e}", "```", ""]
    return "\n".join(lines)


def check_folder(folder: Path) -> str | None:
    """One line saying what is wrong with ``folder``, or None."""
    if not folder.is_dir():
        return f"{folder}: no such folder; give folders written by 'svbrdf-models predict' (OUT/<photo>/)"
    if not (folder / "material.gltf").is_file():
        return f"{folder}: holds no material.gltf; give a folder written by 'svbrdf-models predict'"
    try:
        gltf = json.loads((folder / "material.gltf").read_text())
        images = expected_images(gltf)
    except (ValueError, KeyError, IndexError, TypeError) as e:
        return f"{folder / 'material.gltf'}: not a glTF material this check reads ({e})"
    missing = [role for role, name in images.items() if not name or not (folder / name).is_file()]
    if missing:
        return f"{folder / 'material.gltf'}: its {', '.join(missing)} image is missing; rerun predict"
    from svbrdf_render import SVBRDFError, read_map_folder

    try:  # the project's own maps, which the preview renders
        read_map_folder(folder)
    except SVBRDFError as e:
        return str(e)
    return None


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        prog=PROG, description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    ap.add_argument("folders", nargs="+", type=Path,
                    help="material folders written by 'svbrdf-models predict PHOTO -o OUT' (OUT/<photo>/)")
    ap.add_argument("--frames", default="0,6,12,18",
                    help="which of the preview's 24 lights to render (0 = +X, 6 = +Y, 12 = -X, 18 = -Y; "
                    "default 0,6,12,18)")
    ap.add_argument("--samples", type=int, default=4,
                    help="Cycles samples per pixel (default 4: a point light and a pixel-centre filter "
                    "leave almost no noise)")
    ap.add_argument("--threads", type=int, default=1,
                    help="Cycles and torch threads (default 1: a shared machine runs slower with more)")
    ap.add_argument("--blender", default="blender", help="the Blender executable (default: blender on PATH)")
    ap.add_argument("--timeout", type=float, default=600,
                    help="seconds one Blender run may take (default 600)")
    ap.add_argument("--heat-max", type=float, default=0.2,
                    help="top of the |difference| colour scale, display values (default 0.2)")
    ap.add_argument("-o", "--out", type=Path, default=Path("blender-check"),
                    help="output folder (default blender-check)")
    a = ap.parse_args(argv)
    try:
        frames = sorted({int(x) for x in a.frames.split(",")})
    except ValueError:
        print(f"{PROG}: error: --frames {a.frames!r}: give frame numbers 0-23, e.g. 0,6,12,18",
              file=sys.stderr)
        return 2
    if not frames or any(not 0 <= k < 24 for k in frames):
        print(f"{PROG}: error: --frames {a.frames!r}: frames run from 0 to 23", file=sys.stderr)
        return 2
    if a.samples < 1 or a.threads < 1:
        print(f"{PROG}: error: --samples and --threads must be at least 1", file=sys.stderr)
        return 2
    a.blender_path = shutil.which(a.blender)
    if a.blender_path is None:
        print(f"{PROG}: error: no {a.blender!r} on PATH; install Blender 3.4 or later (Debian: apt-get "
              "install blender python3-numpy) or give --blender PATH", file=sys.stderr)
        return 2
    for folder in a.folders:
        problem = check_folder(folder)
        if problem:
            print(f"{PROG}: error: {problem}", file=sys.stderr)
            return 2
    names = [f.name for f in a.folders]
    if len(set(names)) != len(names):
        print(f"{PROG}: error: two folders share a name; their results would overwrite each other",
              file=sys.stderr)
        return 2
    torch.set_num_threads(a.threads)
    a.out.mkdir(parents=True, exist_ok=True)
    from svbrdf_render import SVBRDFError

    results = []
    for folder in a.folders:
        try:
            r = check_one(folder, a.out, a, frames)
        except BlenderFailed as e:
            print(f"{PROG}: error: {folder}: {e}", file=sys.stderr)
            return 1
        except SVBRDFError as e:  # a damaged map file: one line
            print(f"{PROG}: error: {e}", file=sys.stderr)
            return e.exit_code
        results.append(r)
        mean = sum(row["rmse"] for row in r.rows) / len(r.rows)
        print(f"  {r.name}: mean RMSE {mean:.4f}, calibration {r.calibration:.4f}, "
              f"{r.seconds:.1f} s", file=sys.stderr, flush=True)
    text = table(results, a)
    (a.out / "blender_check.md").write_text(text)
    print(text)
    return 1 if any(r.problems for r in results) else 0


if __name__ == "__main__":
    sys.exit(main())
