"""Run examples/deep_formats.osl through Blender's Cycles (the `bpy` module, built with OSL).

Run by test_deep_formats.py with the Python that has `bpy` (a venv of its own: bpy pins its
own numpy). Reads a JSON job on stdin: {"osl": path of deep_formats.osl, "work": a folder,
"cases": [{"format": "avsm", "size": 8, "texels": [[c0, c1, ...], ...], "u": [u0, ...]}]};
writes {"T": [[[T per u] per texel] per case]} on stdout.

Each case is one render. A wrapper shader (the example's functions, without its shader, and a
shader of its own) holds the texels' coefficients and the depths as constants; the image is
len(u) x len(texels) pixels of an orthographic camera over a plane spanning [0, W] x [0, H],
and pixel (i, j) emits T of texel j at depth u[i]: the shading point P picks them by
floor(P), so the pixel filter's jitter cannot move a sample to its neighbour. Emission seen
directly by the camera is the pixel's value; the EXR is 32-bit float, linear.
"""

import glob
import json
import os
import sys

import bpy

# Cycles' script node reads the compiled shader's parameters with `oslquery`, which the bpy
# wheel ships in Blender's own site-packages, outside sys.path.
sys.path += [
    d
    for p in list(sys.path)
    for d in glob.glob(os.path.join(p, "bpy", "*", "python", "lib", "python3*", "site-packages"))
]


def wrapper(functions: str, case: dict) -> str:
    texels, u = case["texels"], case["u"]
    flat = []
    for t in texels:
        flat += list(t) + [0.0] * (64 - len(t))
    fn = {"fourier": "umbraFourierT", "moments": "umbraMomentsT", "avsm": "umbraAvsmT"}[
        case["format"]
    ]
    return (
        functions
        + "\nshader umbra_test(output float T = 1)\n{\n"
        + f"    float C[{len(flat)}] = {{{', '.join(repr(float(x)) for x in flat)}}};\n"
        + f"    float U[{len(u)}] = {{{', '.join(repr(float(x)) for x in u)}}};\n"
        + f"    int i = clamp((int)floor(P[0]), 0, {len(u) - 1});\n"
        + f"    int j = clamp((int)floor(P[1]), 0, {len(texels) - 1});\n"
        + "    float c[64];\n"
        + "    for (int k = 0; k < 64; ++k) {\n"
        + "        c[k] = C[j * 64 + k];\n"
        + "    }\n"
        + f"    T = {fn}(c, {int(case['size'])}, U[i]);\n"
        + "}\n"
    )


def render(osl_path: str, out: str, w: int, h: int) -> list:
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.shading_system = True  # OSL
    scene.cycles.samples = 1
    scene.cycles.use_denoising = False
    scene.cycles.filter_width = 0.01
    scene.render.resolution_x, scene.render.resolution_y = w, h
    scene.render.resolution_percentage = 100
    scene.render.image_settings.file_format = "OPEN_EXR"
    scene.render.image_settings.color_depth = "32"
    scene.render.image_settings.exr_codec = "NONE"
    scene.render.film_transparent = False
    scene.view_settings.view_transform = "Standard"
    scene.view_settings.look = "None"
    scene.world = bpy.data.worlds.new("black")
    scene.world.color = (0.0, 0.0, 0.0)
    # The plane [0, w] x [0, h] at z = 0, seen from above by an orthographic camera.
    mesh = bpy.data.meshes.new("plane")
    mesh.from_pydata([(0, 0, 0), (w, 0, 0), (w, h, 0), (0, h, 0)], [], [(0, 1, 2, 3)])
    plane = bpy.data.objects.new("plane", mesh)
    scene.collection.objects.link(plane)
    mat = bpy.data.materials.new("umbra")
    mat.use_nodes = True
    nodes, links = mat.node_tree.nodes, mat.node_tree.links
    nodes.clear()
    script = nodes.new("ShaderNodeScript")
    script.mode = "EXTERNAL"
    script.filepath = osl_path
    emit = nodes.new("ShaderNodeEmission")
    emit.inputs["Strength"].default_value = 1.0
    output = nodes.new("ShaderNodeOutputMaterial")
    if "T" not in script.outputs:
        raise SystemExit(f"the OSL script did not compile: {osl_path}")
    links.new(script.outputs["T"], emit.inputs["Color"])
    links.new(emit.outputs["Emission"], output.inputs["Surface"])
    mesh.materials.append(mat)
    cam_data = bpy.data.cameras.new("cam")
    cam_data.type = "ORTHO"
    cam_data.ortho_scale = float(max(w, h))
    cam = bpy.data.objects.new("cam", cam_data)
    cam.location = (w / 2, h / 2, 10.0)
    scene.collection.objects.link(cam)
    scene.camera = cam
    scene.render.filepath = out
    bpy.ops.render.render(write_still=True)
    img = bpy.data.images.load(out)
    px = list(img.pixels)  # RGBA, bottom row first
    rows = []
    for j in range(h):
        rows.append([px[4 * (j * w + i)] for i in range(w)])
    return rows  # rows[j][i]: row j from the bottom = texel j


def main() -> None:
    job = json.load(sys.stdin)
    with open(job["osl"]) as f:
        text = f.read()
    functions = text[: text.index("shader umbra_deep_shadow")]
    results = []
    for n, case in enumerate(job["cases"]):
        path = os.path.join(job["work"], f"case{n}.osl")
        # Cycles renders at least 4 x 4 pixels: pad with copies of the last texel.
        rows = len(case["texels"])
        case = dict(case, texels=case["texels"] + case["texels"][-1:] * max(0, 4 - rows))
        with open(path, "w") as f:
            f.write(wrapper(functions, case))
        out = os.path.join(job["work"], f"case{n}.exr")
        results.append(render(path, out, len(case["u"]), len(case["texels"]))[:rows])
    json.dump({"T": results}, sys.stdout)


if __name__ == "__main__":
    main()
