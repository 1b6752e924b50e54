# Blender (Cycles) as a transmittance peer: render T along orthographic rays through an
# absorption-only volume in front of a white world, framed like vdb_render's ortho camera
# (the convention of ../shared/tools/oracle.py image and bench/programs/ortho_view.rs).
#
#   blender -b --factory-startup -P bench/blender_transmittance.py -- VOL.vdb out.exr \
#       --grid density --scale S --dir=dx,dy,dz --center=cx,cy,cz --up=ux,uy,uz --frame F \
#       --res 512x512 --step-rate 1 --spp 1 --threads 2
#
# Set-up (../shared/research/peers.md section 3):
# - material: Attribute(grid) x scale -> Volume Absorption (colour black, so sigma_a = density
#   per world unit), nothing else; world: white background of strength 1;
# - orthographic camera at CENTER looking along DIR with UP, ortho_scale = frame;
# - pixel filter 0.01 px (one sample at the pixel centre), Standard view transform, no
#   denoising, no adaptive sampling, float EXR; R = G = B = T.
# Cycles puts voxel (i, j, k) at index (i, j, k) + 0.5, so its image must be scored against a
# reference rendered with the grid shifted by half a voxel (ortho_view --index-offset 0.5).
# Prints "CYCLES_RENDER_SECONDS <s>": the render alone, without Blender's start-up and load.
import math
import os
import sys
import time

import bpy
from mathutils import Matrix, Vector

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from bench_args import parse  # noqa: E402


def vec(s):
    return Vector([float(x) for x in s.split(",")])


def main():
    args = sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else []
    vdb, out, opt = parse(
        args,
        "usage: blender -b --factory-startup -P blender_transmittance.py -- VOL.vdb OUT.exr [options]",
    )
    grid = opt.get("grid", "density")
    scale = float(opt.get("scale", "1"))
    d = vec(opt.get("dir", "0,0,-1")).normalized()
    center = vec(opt.get("center", "0,0,0"))
    up = vec(opt.get("up", "0,1,0"))
    frame = float(opt.get("frame", "1"))
    w, h = (int(x) for x in opt.get("res", "512x512").split("x"))
    step_rate = float(opt.get("step-rate", "1"))
    spp = int(opt.get("spp", "1"))
    threads = int(opt.get("threads", "0"))
    seed = int(opt.get("seed", "0"))

    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene

    # The volume, its grid's own transform applied by Blender.
    volume = bpy.data.volumes.new("vol")
    volume.filepath = vdb
    volume.grids.load()
    if grid not in [g.name for g in volume.grids]:
        sys.exit(f"{vdb}: no grid named {grid}")
    volume.render.space = "OBJECT"
    volume.render.step_size = 0.0  # automatic: one voxel, times the scene's step rate
    obj = bpy.data.objects.new("vol", volume)
    scene.collection.objects.link(obj)

    mat = bpy.data.materials.new("absorb")
    mat.use_nodes = True
    nodes, links = mat.node_tree.nodes, mat.node_tree.links
    nodes.clear()
    attr = nodes.new("ShaderNodeAttribute")
    attr.attribute_name = grid
    mul = nodes.new("ShaderNodeMath")
    mul.operation = "MULTIPLY"
    mul.inputs[1].default_value = scale
    absorb = nodes.new("ShaderNodeVolumeAbsorption")
    absorb.inputs["Color"].default_value = (0.0, 0.0, 0.0, 1.0)
    output = nodes.new("ShaderNodeOutputMaterial")
    links.new(attr.outputs["Fac"], mul.inputs[0])
    links.new(mul.outputs["Value"], absorb.inputs["Density"])
    links.new(absorb.outputs["Volume"], output.inputs["Volume"])
    volume.materials.append(mat)

    world = bpy.data.worlds.new("white")
    world.use_nodes = True
    bg = world.node_tree.nodes["Background"]
    bg.inputs["Color"].default_value = (1.0, 1.0, 1.0, 1.0)
    bg.inputs["Strength"].default_value = 1.0
    scene.world = world

    # Orthographic camera: looks along its local -z with local +y up.
    u = (up - up.dot(d) * d).normalized()
    r = d.cross(u)
    cam_data = bpy.data.cameras.new("cam")
    cam_data.type = "ORTHO"
    cam_data.ortho_scale = frame
    cam_data.sensor_fit = "HORIZONTAL"
    cam_data.clip_start = 1e-6
    cam_data.clip_end = 1e9
    cam = bpy.data.objects.new("cam", cam_data)
    rot = Matrix((r, u, -d)).transposed()
    cam.matrix_world = Matrix.Translation(center) @ rot.to_4x4()
    scene.collection.objects.link(cam)
    scene.camera = cam

    scene.render.engine = "CYCLES"
    cy = scene.cycles
    cy.device = "CPU"
    cy.samples = spp
    cy.use_adaptive_sampling = False
    cy.use_denoising = False
    cy.seed = seed
    cy.volume_step_rate = step_rate
    cy.volume_max_steps = 1 << 20
    cy.max_bounces = 0
    cy.transparent_max_bounces = 0
    cy.filter_width = 0.01
    scene.render.resolution_x, scene.render.resolution_y = w, h
    scene.render.resolution_percentage = 100
    scene.render.film_transparent = False
    scene.view_settings.view_transform = "Standard"
    scene.view_settings.look = "None"
    scene.view_settings.exposure = 0.0
    scene.view_settings.gamma = 1.0
    scene.render.threads_mode = "FIXED" if threads > 0 else "AUTO"
    if threads > 0:
        scene.render.threads = threads
    settings = scene.render.image_settings
    settings.file_format = "OPEN_EXR"
    settings.color_depth = "32"
    settings.color_mode = "RGB"
    scene.render.filepath = out
    scene.render.use_file_extension = False

    t = time.perf_counter()
    bpy.ops.render.render(write_still=True)
    print(f"CYCLES_RENDER_SECONDS {time.perf_counter() - t:.6f}", flush=True)


main()
