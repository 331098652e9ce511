"""Blender scene for line-only Freestyle renders (import only inside a bpy process).

Cycles on CPU with one sample, no denoising and no light bounces renders nothing but a
transparent film (``use_solid`` off); Freestyle draws visible silhouette, border and crease
lines on top. The worker composites the RGBA result onto white.
"""

from __future__ import annotations

import math
from pathlib import Path

import bpy
import numpy as np

from render.cameras import View, blender_matrix_world
from render.settings import EDGE_TYPES, RenderSettings

MODEL_NAME = "model"


def build_scene(settings: RenderSettings) -> bpy.types.Scene:
    """Reset Blender to an empty scene configured for the given settings; returns the scene."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    r = scene.render
    r.engine = "CYCLES"
    r.resolution_x = r.resolution_y = settings.image_size
    r.resolution_percentage = 100
    r.pixel_aspect_x = r.pixel_aspect_y = 1.0
    r.film_transparent = True
    r.threads_mode = "FIXED"
    r.threads = settings.threads
    r.use_persistent_data = True
    r.image_settings.file_format = "PNG"
    r.image_settings.color_mode = "RGBA"
    r.image_settings.color_depth = "8"
    r.image_settings.compression = 0  # a temp file read back at once: don't spend time deflating

    c = scene.cycles
    c.device = "CPU"
    c.samples = settings.samples
    c.use_adaptive_sampling = False
    c.use_denoising = False
    c.max_bounces = 0
    c.seed = 0
    c.use_animated_seed = False

    scene.view_settings.view_transform = "Standard"
    scene.view_settings.look = "None"
    scene.display_settings.display_device = "sRGB"

    _setup_freestyle(scene, settings)
    _setup_camera(scene, settings)
    return scene


def _setup_freestyle(scene: bpy.types.Scene, settings: RenderSettings) -> None:
    r = scene.render
    r.use_freestyle = True
    r.line_thickness_mode = "ABSOLUTE"
    r.line_thickness = 1.0
    layer = scene.view_layers[0]
    layer.use_solid = False  # lines only: surfaces contribute nothing but occlusion
    layer.use_freestyle = True
    fs = layer.freestyle_settings
    fs.mode = "EDITOR"
    fs.crease_angle = math.radians(settings.crease_angle_deg)
    fs.use_culling = True
    fs.use_smoothness = settings.smooth_shading
    for old in list(fs.linesets):
        fs.linesets.remove(old)
    ls = fs.linesets.new("lines")
    ls.select_by_visibility = True
    ls.visibility = "VISIBLE"
    ls.select_by_edge_types = True
    ls.edge_type_negation = "INCLUSIVE"
    ls.edge_type_combination = "OR"
    for edge_type in EDGE_TYPES:
        setattr(ls, f"select_{edge_type}", edge_type in settings.edge_types)
    style = bpy.data.linestyles.new("ink")
    style.color = (0.0, 0.0, 0.0)
    style.alpha = 1.0
    style.thickness = settings.line_thickness
    style.thickness_position = "CENTER"
    style.caps = "BUTT"
    style.chaining = "PLAIN"
    # Selected before any shader runs, so dropped specks are neither drawn nor captured.
    style.use_length_min = settings.min_stroke_px > 0
    style.length_min = max(0.0, settings.min_stroke_px)
    ls.linestyle = style


def _setup_camera(scene: bpy.types.Scene, settings: RenderSettings) -> None:
    cam_data = bpy.data.cameras.new("camera")
    if settings.orthographic:
        cam_data.type = "ORTHO"
        cam_data.ortho_scale = settings.ortho_scale
    else:
        cam_data.type = "PERSP"
        cam_data.lens_unit = "MILLIMETERS"
        cam_data.lens = settings.lens_mm
    cam_data.sensor_fit = "HORIZONTAL"
    cam_data.sensor_width = settings.sensor_mm
    cam_data.shift_x = cam_data.shift_y = 0.0
    cam_data.clip_start = 0.01
    cam_data.clip_end = 100.0
    cam = bpy.data.objects.new("camera", cam_data)
    scene.collection.objects.link(cam)
    scene.camera = cam


def set_camera(scene: bpy.types.Scene, view: View) -> None:
    from mathutils import Matrix

    scene.camera.matrix_world = Matrix(blender_matrix_world(view).tolist())


def set_mesh(
    scene: bpy.types.Scene, vertices: np.ndarray, faces: np.ndarray, smooth_below_deg: float | None = None
) -> None:
    """Replace the scene's model by a triangle mesh.

    Flat-shaded when ``smooth_below_deg`` is None: silhouettes then follow mesh edges exactly but
    zig-zag across finely tessellated curved surfaces. Otherwise shaded smooth with edges sharper
    than ``smooth_below_deg`` (angle between face normals) kept sharp, so Freestyle (with
    use_smoothness) draws silhouettes of curved parts as smooth curves across faces.
    """
    old = bpy.data.objects.get(MODEL_NAME)
    if old is not None:
        mesh = old.data
        bpy.data.objects.remove(old, do_unlink=True)
        bpy.data.meshes.remove(mesh)
    mesh = bpy.data.meshes.new(MODEL_NAME)
    nv, nf = len(vertices), len(faces)
    mesh.vertices.add(nv)
    mesh.vertices.foreach_set("co", np.ascontiguousarray(vertices, np.float32).ravel())
    mesh.loops.add(3 * nf)
    mesh.loops.foreach_set("vertex_index", np.ascontiguousarray(faces, np.int32).ravel())
    mesh.polygons.add(nf)
    mesh.polygons.foreach_set("loop_start", np.arange(0, 3 * nf, 3, dtype=np.int32))
    mesh.update(calc_edges=True)
    mesh.validate(verbose=False)
    if smooth_below_deg is not None:
        mesh.shade_smooth()
        mesh.set_sharp_from_angle(angle=math.radians(smooth_below_deg))
    obj = bpy.data.objects.new(MODEL_NAME, mesh)
    scene.collection.objects.link(obj)


def render_png(scene: bpy.types.Scene, path: Path) -> None:
    """Render the current view to an RGBA PNG (Render Result can't be read back headless)."""
    scene.render.filepath = str(path)
    bpy.ops.render.render(write_still=True)
