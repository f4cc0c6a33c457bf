"""Material and world node trees -> the diffuse model's constants (albedo, emission).

``MaterialReader`` evaluates the closure feeding a Material or World output: Principled
and Diffuse BSDFs give an albedo, Emission/Background nodes give emission, Mix/Add
Shaders are combined, textured colours become the image's average (solid-angle weighted
for equirectangular environments), and everything approximated is reported as a warning.
"""
from __future__ import annotations

import math

import numpy as np

# Reflective BSDFs that are not diffuse: approximated by their colour for now.
_OTHER_BSDFS = {
    "ShaderNodeBsdfAnisotropic", "ShaderNodeBsdfGlossy", "ShaderNodeBsdfGlass",
    "ShaderNodeBsdfMetallic", "ShaderNodeBsdfRefraction", "ShaderNodeBsdfSheen",
    "ShaderNodeBsdfToon", "ShaderNodeBsdfTranslucent", "ShaderNodeSubsurfaceScattering",
    "ShaderNodeBsdfHair", "ShaderNodeBsdfHairPrincipled", "ShaderNodeBsdfVelvet",
}
# Roughness up to which a metallic or glossy BSDF is a perfect planar mirror.
MIRROR_ROUGHNESS = 1e-3
# Closures that reflect nothing (black for the diffuse model).
_BLACK_CLOSURES = {"ShaderNodeBsdfTransparent", "ShaderNodeHoldout",
                   "ShaderNodeBsdfRayPortal"}


def _first3(value):
    return np.array(tuple(value)[:3], np.float32)


def _follow(socket):
    """The output socket feeding ``socket``, skipping reroutes and muted links; or None."""
    seen = 0
    while socket.is_linked and seen < 64:
        link = socket.links[0]
        if getattr(link, "is_muted", False) or not getattr(link, "is_valid", True):
            return None
        node = link.from_node
        if node.bl_idname == "NodeReroute":
            socket = node.inputs[0]
            seen += 1
            continue
        return link.from_socket
    return None


def _srgb_to_linear(c):
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


class MaterialReader:
    """Turns node trees into the diffuse model's constants; collects warnings."""

    def __init__(self, warnings):
        self.warnings = warnings
        self._image_avg = {}

    def warn(self, message):
        if message not in self.warnings:
            self.warnings.append(message)

    # ----- sockets
    def image_average(self, image, equirect=False):
        key = (image.name_full, equirect)
        if key in self._image_avg:
            return self._image_avg[key]
        avg = None
        try:
            w, h = image.size
            ch = image.channels
            if w > 0 and h > 0 and ch >= 3:
                px = np.empty(w * h * ch, np.float32)
                image.pixels.foreach_get(px)
                px = px.reshape(h, w, ch)[:, :, :3].astype(np.float64)
                # Byte images hold display-encoded values; float buffers are linear.
                if not image.is_float and image.colorspace_settings.name == "sRGB":
                    px = _srgb_to_linear(px)
                if equirect:      # solid-angle weights of the rows (bottom-up)
                    lat = (np.arange(h) + 0.5) / h * math.pi - math.pi / 2
                    wts = np.cos(lat)
                    avg = (px.mean(axis=1) * wts[:, None]).sum(axis=0) / wts.sum()
                else:
                    avg = px.mean(axis=(0, 1))
                avg = avg.astype(np.float32)
        except Exception:         # missing file, unsupported format...
            avg = None
        self._image_avg[key] = avg
        return avg

    def color(self, node, name, fallback, owner):
        """Constant linear RGB of an input socket; texture -> image average or fallback.

        ``fallback`` (None: the socket's own unlinked value) replaces other linked nodes.
        """
        socket = node.inputs[name]
        src = _follow(socket)
        if not socket.is_linked:
            return _first3(socket.default_value)
        if src is None:                   # muted link: Blender uses the socket value
            return _first3(socket.default_value)
        from_node = src.node
        if from_node.bl_idname == "ShaderNodeRGB":
            return _first3(src.default_value)
        image = getattr(from_node, "image", None)
        if from_node.bl_idname in ("ShaderNodeTexImage", "ShaderNodeTexEnvironment") \
                and image is not None:
            equirect = (from_node.bl_idname == "ShaderNodeTexEnvironment"
                        and from_node.projection == "EQUIRECTANGULAR")
            avg = self.image_average(image, equirect)
            if avg is not None:
                self.warn(f"{owner}: '{name}' is textured; using the average colour of "
                          f"image '{image.name}'")
                return avg
        if fallback is None:
            fallback = socket.default_value
        self.warn(f"{owner}: '{name}' is driven by a '{from_node.name}' node; "
                  f"using a constant colour instead")
        return _first3(fallback)

    def value(self, node, name, owner):
        socket = node.inputs[name]
        if socket.is_linked:
            src = _follow(socket)
            if src is not None and src.node.bl_idname == "ShaderNodeValue":
                return float(src.default_value)
            if src is not None:
                self.warn(f"{owner}: '{name}' is driven by a '{src.node.name}' node; "
                          f"using its unlinked value {socket.default_value:g}")
        return float(socket.default_value)

    def is_mirror(self, node, owner):
        return (self.value(node, "Metallic", owner) >= 1.0 - MIRROR_ROUGHNESS
                and self.value(node, "Roughness", owner) <= MIRROR_ROUGHNESS)

    # ----- closures
    def closure(self, socket, fallback, owner, depth=0):
        """Evaluate the closure feeding ``socket``.

        Returns ``(albedo (3,), emission (3,), kind)``, kind being 'diffuse' (a diffuse
        BSDF), 'black' (emits or absorbs only), 'other' (a non-diffuse BSDF approximated
        by its colour) or 'none' (nothing connected).
        """
        zero = np.zeros(3, np.float32)
        src = _follow(socket)
        if src is None or depth > 64:
            return zero, zero, "none"
        node = src.node
        kind = node.bl_idname
        if kind == "ShaderNodeBsdfPrincipled" and self.is_mirror(node, owner):
            # Fully metallic, roughness 0: a mirror reflecting its base colour.
            return self.color(node, "Base Color", fallback, owner), zero, "mirror"
        # Blender 4.0+ creates Glossy BSDFs as ShaderNodeBsdfAnisotropic.
        if (kind in ("ShaderNodeBsdfGlossy", "ShaderNodeBsdfAnisotropic")
                and self.value(node, "Roughness", owner) <= MIRROR_ROUGHNESS):
            return self.color(node, "Color", fallback, owner), zero, "mirror"
        if kind == "ShaderNodeBsdfPrincipled":
            # Partly metallic or rough: approximated as diffuse with its base colour.
            albedo = self.color(node, "Base Color", fallback, owner)
            emission = (self.color(node, "Emission Color", None, owner)
                        * self.value(node, "Emission Strength", owner))
            return albedo, emission.astype(np.float32), "diffuse"
        if kind == "ShaderNodeBsdfDiffuse":
            return self.color(node, "Color", fallback, owner), zero, "diffuse"
        if kind in ("ShaderNodeEmission", "ShaderNodeBackground"):
            emission = (self.color(node, "Color", fallback if kind == "ShaderNodeBackground"
                                   else None, owner)
                        * self.value(node, "Strength", owner))
            return zero, emission.astype(np.float32), "black"
        if kind in ("ShaderNodeMixShader", "ShaderNodeAddShader"):
            if kind == "ShaderNodeMixShader":
                fac_socket = node.inputs[0]
                if fac_socket.is_linked:
                    self.warn(f"{owner}: a Mix Shader factor is driven by a node; "
                              f"mixing 50/50")
                    f = 0.5
                else:
                    f = min(max(float(fac_socket.default_value), 0.0), 1.0)
                wa, wb = 1.0 - f, f
                sa, sb = node.inputs[1], node.inputs[2]
            else:
                wa = wb = 1.0
                sa, sb = node.inputs[0], node.inputs[1]
            aa, ea, ka = self.closure(sa, fallback, owner, depth + 1)
            ab, eb, kb = self.closure(sb, fallback, owner, depth + 1)
            emission = (wa * ea + wb * eb).astype(np.float32)
            if ka == "none" and kb == "none":
                return zero, emission, "none"
            # A non-diffuse BSDF mixed with a diffuse one: keep the diffuse one's colour
            # (the "first BSDF found" rule); otherwise weight the albedos.
            if ka == "other" and kb in ("diffuse", "black"):
                return ab, emission, kb
            if kb == "other" and ka in ("diffuse", "black"):
                return aa, emission, ka
            albedo = np.clip(wa * aa + wb * ab, 0, 1).astype(np.float32)
            kinds = {ka, kb} - {"none"}
            if kinds == {"mirror"}:
                return albedo, emission, "mirror"
            if "mirror" in kinds:
                self.warn(f"{owner}: a mirror mixed with another shader is approximated "
                          f"as diffuse")
            out = ("diffuse" if "diffuse" in kinds else
                   "other" if "other" in kinds else "black")
            return albedo, emission, out
        if kind in _BLACK_CLOSURES:
            return zero, zero, "black"
        if kind in _OTHER_BSDFS:
            for name in ("Color", "Base Color"):
                if name in node.inputs:
                    return self.color(node, name, fallback, owner), zero, "other"
            return np.asarray(fallback, np.float32)[:3], zero, "other"
        self.warn(f"{owner}: unsupported shader node '{node.name}' ({kind}); "
                  f"using the viewport colour")
        return np.asarray(fallback, np.float32)[:3], zero, "other"

    # ----- datablocks
    def material(self, mat):
        """(albedo (3,), emission (3,), mirror reflectance (3,)) of a bpy Material."""
        owner = f"Material '{mat.name}'"
        fallback = tuple(mat.diffuse_color)[:3]
        zero = np.zeros(3, np.float32)
        tree = mat.node_tree
        if tree is None:                      # legacy material without nodes
            return np.array(fallback, np.float32), zero, zero
        output = _active_output(tree, "ShaderNodeOutputMaterial")
        if output is None:
            return zero, zero, zero
        albedo, emission, kind = self.closure(output.inputs["Surface"], fallback, owner)
        if kind == "other":
            self.warn(f"{owner}: non-diffuse BSDF approximated as diffuse")
        albedo = np.clip(albedo, 0, 1).astype(np.float32)
        emission = np.maximum(emission, 0).astype(np.float32)
        if kind == "mirror":
            return zero, emission, albedo
        return albedo, emission, zero

    def world(self, world):
        """Constant background radiance (3,) of a bpy World."""
        if world is None:
            return np.zeros(3, np.float32)
        owner = f"World '{world.name}'"
        fallback = tuple(world.color)[:3]
        tree = world.node_tree                 # Blender 5.0: worlds always use nodes
        if tree is None:
            return np.array(fallback, np.float32)
        output = _active_output(tree, "ShaderNodeOutputWorld")
        if output is None:
            return np.zeros(3, np.float32)
        _, emission, _ = self.closure(output.inputs["Surface"], fallback, owner)
        return np.maximum(emission, 0).astype(np.float32)


def _active_output(tree, idname):
    outputs = [n for n in tree.nodes if n.bl_idname == idname]
    if not outputs:
        return None
    for rank in (lambda n: n.is_active_output and n.target in ("ALL", "CYCLES"),
                 lambda n: n.target in ("ALL", "CYCLES"),
                 lambda n: True):
        for n in outputs:
            if rank(n):
                return n
