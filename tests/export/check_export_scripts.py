#!/usr/bin/env python3
"""The Blender and MaterialX exports of `anisocap export`, checked without Blender or MaterialX:
the Blender script parses (python's ast) and builds a Principled BSDF whose anisotropy, rotation,
tangent, normal, IOR, tint, colour and roughness inputs (and for Blender 3.x, Specular and Metallic)
are all linked from texture or map nodes of the right kinds, and names the export folder's absolute
path for its textures (the Blender renders themselves: check_blender_render.py); `--tileable`
exports a tile and refuses an overlap too small to blend; the MaterialX document is well-formed XML binding every Standard Surface input it
sets to an image of a file that exists, with matching types.
Usage: check_export_scripts.py ANISOCAP_PROGRAM"""
import ast
import os
import subprocess
import sys
import tempfile
import xml.etree.ElementTree as ET


def fail(message):
    print("check_export_scripts: " + message)
    sys.exit(1)


def check_blender(folder):
    source = open(os.path.join(folder, "material.py")).read()
    tree = ast.parse(source)
    created = {}  # variable name -> node type
    links = []  # (from variable, from socket, to variable, to socket)
    textures = {}  # variable or call -> file
    for node in ast.walk(tree):
        if isinstance(node, ast.Assign) and isinstance(node.value, ast.Call):
            call = node.value
            if isinstance(call.func, ast.Attribute) and call.func.attr == "new" and call.args and isinstance(call.args[0], ast.Constant):
                for target in node.targets:
                    if isinstance(target, ast.Name):
                        created[target.id] = call.args[0].value
        if isinstance(node, ast.Call) and isinstance(node.func, ast.Name) and node.func.id == "link" and len(node.args) == 4:
            source_arg, from_socket, to_arg, to_socket = node.args
            if isinstance(source_arg, ast.Call) and isinstance(source_arg.func, ast.Name) and source_arg.func.id == "texture":
                source_name = "texture:" + source_arg.args[0].value
            else:
                source_name = source_arg.id
            links.append((source_name, from_socket.value, to_arg.id, to_socket.value))
    for needed in ["ShaderNodeBsdfPrincipled", "ShaderNodeOutputMaterial", "ShaderNodeTexImage", "ShaderNodeNormalMap", "ShaderNodeTangent", "ShaderNodeUVMap"]:
        if needed not in created.values() and needed not in source:
            fail(f"the Blender script creates no {needed}")
    principled = [name for name, kind in created.items() if kind == "ShaderNodeBsdfPrincipled"]
    if len(principled) != 1:
        fail("expected one Principled BSDF node")
    into = {to_socket: (src, from_socket) for src, from_socket, to, to_socket in links if to == principled[0]}
    for socket in ["Base Color", "Roughness", "Anisotropic", "Anisotropic Rotation", "IOR", "Specular Tint", "Specular", "Metallic", "Normal", "Tangent"]:
        if socket not in into:
            fail(f"Principled BSDF input '{socket}' is not linked")
    if created.get(into["Tangent"][0]) != "ShaderNodeTangent" or "direction_type = \"UV_MAP\"" not in source:
        fail("the tangent does not come from a Tangent node on the UV map")
    if created.get(into["Normal"][0]) != "ShaderNodeNormalMap":
        fail("the normal does not come from a Normal Map node")
    if "bpy.app.version >= (4, 0, 0)" not in source:
        fail("the Blender script does not set its Fresnel inputs per Blender version")
    folders = [node.value.value for node in ast.walk(tree) if isinstance(node, ast.Assign) and any(isinstance(t, ast.Name) and t.id == "TEXTURES" for t in node.targets)]
    if folders != [os.path.abspath(folder)]:
        fail(f"the Blender script's TEXTURES is {folders}, not the export folder {os.path.abspath(folder)}")
    for socket in ["Base Color", "Roughness", "Anisotropic", "Anisotropic Rotation", "IOR", "Specular Tint", "Specular", "Metallic"]:
        src = into[socket][0]
        if not src.startswith("texture:") or not os.path.exists(os.path.join(folder, src[len("texture:"):])):
            fail(f"'{socket}' is not read from an exported texture file")
    if not any(src == principled[0] and to_socket == "Surface" for src, _, to, to_socket in links):
        fail("the Principled BSDF is not linked to the output")
    print(f"blender: {len(created)} nodes, {len(links)} links, Principled inputs linked: {sorted(into)}")


def check_materialx(folder):
    root = ET.parse(os.path.join(folder, "material.mtlx")).getroot()
    if root.tag != "materialx":
        fail("not a MaterialX document")
    nodes = {n.get("name"): n for n in root}
    surfaces = [n for n in root if n.tag == "standard_surface"]
    if len(surfaces) != 1:
        fail("expected one standard_surface node")
    bound = {}
    for entry in surfaces[0]:
        name, kind = entry.get("name"), entry.get("type")
        source = entry.get("nodename")
        if source is None:
            continue
        if source not in nodes:
            fail(f"input {name} refers to a missing node {source}")
        node = nodes[source]
        if node.get("type") != kind:
            fail(f"input {name} ({kind}) is bound to a {node.get('type')} node")
        if node.tag == "image":
            file = [i.get("value") for i in node if i.get("name") == "file"][0]
            if not os.path.exists(os.path.join(folder, file)):
                fail(f"image {file} of input {name} is missing")
        bound[name] = node.tag
    for needed in ["base_color", "specular", "specular_color", "specular_roughness", "specular_anisotropy", "specular_rotation", "specular_IOR", "normal"]:
        if needed not in bound:
            fail(f"standard_surface input {needed} is not bound to a texture")
    if bound["normal"] != "normalmap":
        fail("the normal does not come through a normalmap node")
    materials = [n for n in root if n.tag == "surfacematerial"]
    if not materials or materials[0][0].get("nodename") != surfaces[0].get("name"):
        fail("no surfacematerial uses the standard_surface")
    print(f"mtlx: standard_surface inputs bound: {sorted(bound)}")


def main():
    program = sys.argv[1]
    with tempfile.TemporaryDirectory() as work:
        subprocess.run([program, "synthesize", "-o", f"{work}/syn", "--width", "32", "--height", "32", "--images", "4", "--seed", "5"], check=True)
        subprocess.run([program, "export", f"{work}/syn/truth", "--format", "blender", "-o", f"{work}/blender"], check=True)
        subprocess.run([program, "export", f"{work}/syn/truth", "--format", "mtlx", "-o", f"{work}/mtlx"], check=True)
        check_blender(f"{work}/blender")
        check_materialx(f"{work}/mtlx")
        tile = subprocess.run([program, "export", f"{work}/syn/truth", "--format", "blender", "--tileable", "-o", f"{work}/tile"], capture_output=True, text=True)
        if tile.returncode != 0 or "made into a" not in tile.stderr or not os.path.exists(f"{work}/tile/material.py"):
            fail(f"export --tileable failed: {tile.stderr}")
        check_blender(f"{work}/tile")
        small = subprocess.run([program, "export", f"{work}/syn/truth", "--format", "blender", "--tileable", "--tile-overlap", "0.03", "-o", f"{work}/small"],
                               capture_output=True, text=True)
        if small.returncode == 0 or "--tileable" not in small.stderr or os.path.exists(f"{work}/small"):
            fail("an overlap of under 2 texels must fail with a message naming --tileable and write nothing")
        bad = subprocess.run([program, "export", f"{work}/nothing", "--format", "gltf", "-o", f"{work}/x.gltf"], capture_output=True, text=True)
        if bad.returncode == 0 or "nothing" not in bad.stderr or os.path.exists(f"{work}/x.gltf"):
            fail("exporting a missing map set must fail with a message naming it and write nothing")


main()
