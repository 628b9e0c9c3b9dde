"""Reflectance and emission of a Blender material, read from its shader nodes.

Supported (walking back from the active Material Output's Surface socket):
- Principled BSDF: reflectance = Base Color, emission = Emission Color x Emission Strength;
- Diffuse BSDF: reflectance = Color;
- Emission: emission = Color x Strength (reflectance 0, like Cycles);
- Add Shader (sum) and Mix Shader (mix by an unconnected Fac) of the above; Reroute nodes.
A colour socket may be fed by an Image Texture (its average colour, linearised from sRGB for 8-bit
images) or an RGB node; a strength socket by a Value node. Anything else gives a warning naming
the material and falls back to the socket's own value (or, for an unknown shader, the default
grey). Emission is radiance in Cycles units (W sr^-1 m^-2: strength x colour).
"""

from dataclasses import dataclass, field

import bpy
import numpy as np

from ..io.images import srgb_to_linear

DEFAULT_REFLECTANCE = 0.8  # objects without a material, and unsupported shaders
MAX_REFLECTANCE = 0.99  # a diffuse surface must absorb some light (the solver needs rho < 1)
PREVIEW = "HR Preview"  # name prefix of the preview nodes / material (ignored when reading)


@dataclass
class Surface:
    reflectance: np.ndarray
    emission: np.ndarray
    warnings: list = field(default_factory=list)


class _Unsupported(Exception):
    pass


_image_cache = {}


def image_average(img):
    """Average linear RGB of an image, or None if it has no pixels."""
    key = (img.name_full, img.filepath, tuple(img.size), img.is_dirty, img.colorspace_settings.name)
    if key in _image_cache and not img.is_dirty:
        return _image_cache[key]
    w, h = img.size
    if w * h == 0 or not img.has_data and not _try_load(img):
        return None
    px = np.empty(w * h * img.channels, np.float32)
    img.pixels.foreach_get(px)
    px = px.reshape(-1, img.channels)
    rgb = px[:, :3] if img.channels >= 3 else np.repeat(px[:, :1], 3, 1)
    avg = rgb.astype(np.float64).mean(0)
    if not img.is_float and img.colorspace_settings.name in ("sRGB", "Filmic sRGB", "AgX Base sRGB"):
        avg = srgb_to_linear(rgb.astype(np.float64)).mean(0)
    if len(_image_cache) > 64:
        _image_cache.clear()
    _image_cache[key] = avg
    return avg


def _try_load(img):
    try:
        img.pixels[0]  # forces a load
    except Exception:
        return False
    return img.has_data


class _Reader:
    def __init__(self, mat):
        self.mat = mat
        self.warnings = []

    def warn(self, msg):
        self.warnings.append(f"Material '{self.mat.name}': {msg}")

    def source(self, socket):
        """The node and output socket feeding `socket`, skipping reroutes and muted links."""
        seen = 0
        while socket.is_linked and seen < 64:
            link = socket.links[0]
            if getattr(link, "is_muted", False):
                return None, None
            node = link.from_node
            if node.type == "REROUTE":
                socket = node.inputs[0]
                seen += 1
                continue
            return node, link.from_socket
        return None, None

    def color(self, socket):
        node, out = self.source(socket)
        if node is None:
            return np.array(socket.default_value[:3], float)
        if node.type == "TEX_IMAGE":
            img = node.image
            avg = image_average(img) if img is not None else None
            if avg is None:
                self.warn(f"image texture '{node.name}' has no pixels; using the socket colour")
                return np.array(socket.default_value[:3], float)
            if out.name == "Alpha":
                return np.full(3, float(avg.mean()))
            return avg
        if node.type == "RGB":
            return np.array(node.outputs[0].default_value[:3], float)
        self.warn(
            f"'{socket.name}' is driven by a '{node.bl_label}' node, which is not supported; "
            "using the socket's own colour"
        )
        return np.array(socket.default_value[:3], float)

    def value(self, socket):
        node, _ = self.source(socket)
        if node is None:
            return float(socket.default_value)
        if node.type == "VALUE":
            return float(node.outputs[0].default_value)
        self.warn(
            f"'{socket.name}' is driven by a '{node.bl_label}' node, which is not supported; "
            "using the socket's own value"
        )
        return float(socket.default_value)

    def shader(self, socket, depth=0):
        node, _ = self.source(socket)
        if node is None:
            raise _Unsupported("nothing is connected to the Surface output")
        if depth > 16:
            raise _Unsupported("shader nesting too deep")
        if node.mute:
            raise _Unsupported(f"the '{node.bl_label}' node is muted")
        t = node.type
        zero = np.zeros(3)
        if t == "BSDF_PRINCIPLED":
            return (
                self.color(node.inputs["Base Color"]),
                self.color(node.inputs["Emission Color"]) * self.value(node.inputs["Emission Strength"]),
            )
        if t == "BSDF_DIFFUSE":
            return self.color(node.inputs["Color"]), zero
        if t == "EMISSION":
            return zero, self.color(node.inputs["Color"]) * self.value(node.inputs["Strength"])
        if t == "ADD_SHADER":
            a, b = self.shader(node.inputs[0], depth + 1), self.shader(node.inputs[1], depth + 1)
            return a[0] + b[0], a[1] + b[1]
        if t == "MIX_SHADER":
            f = min(max(self.value(node.inputs[0]), 0.0), 1.0)
            a, b = self.shader(node.inputs[1], depth + 1), self.shader(node.inputs[2], depth + 1)
            return (1 - f) * a[0] + f * b[0], (1 - f) * a[1] + f * b[1]
        raise _Unsupported(
            f"the '{node.bl_label}' shader is not supported (use Principled BSDF, Diffuse BSDF or Emission)"
        )


def _output_node(tree):
    outs = [n for n in tree.nodes if n.type == "OUTPUT_MATERIAL" and not n.name.startswith(PREVIEW)]
    for test in (
        lambda n: n.is_active_output and n.target in ("ALL", "CYCLES"),
        lambda n: n.target in ("ALL", "CYCLES"),
        lambda n: True,
    ):
        for n in outs:
            if test(n):
                return n
    return None


def read_material(mat) -> Surface:
    """Reflectance (3,) and emitted radiance (3,) of `mat` (None: default grey, no emission)."""
    grey = np.full(3, DEFAULT_REFLECTANCE)
    if mat is None or mat.get("hr_preview"):
        return Surface(grey, np.zeros(3))
    r = _Reader(mat)
    tree = mat.node_tree
    no_nodes = tree is None or (bpy.app.version < (5, 0, 0) and not mat.use_nodes)
    if no_nodes:
        rho, em = np.array(mat.diffuse_color[:3], float), np.zeros(3)
    else:
        out = _output_node(tree)
        try:
            if out is None:
                raise _Unsupported("no Material Output node")
            rho, em = r.shader(out.inputs["Surface"])
        except _Unsupported as exc:
            r.warn(f"{exc}; using grey {DEFAULT_REFLECTANCE} without emission")
            rho, em = grey.copy(), np.zeros(3)
    rho = np.asarray(rho, float)
    em = np.asarray(em, float)
    if not (np.isfinite(rho).all() and np.isfinite(em).all()):
        r.warn("non-finite colour or strength; using grey without emission")
        rho, em = grey.copy(), np.zeros(3)
    if (rho > MAX_REFLECTANCE).any():
        r.warn(
            f"reflectance {tuple(round(float(x), 4) for x in rho)} clamped to {MAX_REFLECTANCE} "
            "(a diffuse surface cannot reflect all the light it receives)"
        )
    if (rho < 0).any() or (em < 0).any():
        r.warn("negative colour or strength clamped to 0")
    return Surface(np.clip(rho, 0.0, MAX_REFLECTANCE), np.maximum(em, 0.0), r.warnings)
