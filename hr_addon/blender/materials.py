"""Reflectance and emission of a Blender material, read from its shader nodes.

Supported (walking back from the active Material Output's Surface socket):
- Principled BSDF: reflectance = Base Color, emission = Emission Color x Emission Strength;
- Diffuse BSDF: reflectance = Color;
- Emission: emission = Color x Strength (reflectance 0, like Cycles);
- Add Shader (sum) and Mix Shader (mix by an unconnected Fac) of the above; Reroute nodes;
- node groups: a Group node is followed into its tree (the Group Output's input, and back out
  through the Group Input to the Group node's inputs), so a shader inside a group is read.
A colour socket may be fed by an Image Texture (its average colour, linearised from sRGB for 8-bit
images), an RGB node or a Mix node (Color: Mix or Multiply, of those, by an unconnected Factor); a
strength socket by a Value node. albedo_texture() describes the simple textured case (one diffuse
shader whose colour is an Image Texture in its UV map, optionally through one Mix node with a
colour) so that the texture output can show the texture per texel. Anything else gives a warning naming
the material and falls back to the socket's own value (or, for an unknown shader, the default
grey). Emission is radiance in Cycles units (W sr^-1 m^-2: strength x colour).
"""

from dataclasses import dataclass, field

import bpy
import numpy as np

from ..io.images import srgb_to_linear
from .names import PREVIEW

DEFAULT_REFLECTANCE = 0.8  # objects without a material, and unsupported shaders
MAX_REFLECTANCE = 0.99  # a diffuse surface must absorb some light (the solver needs rho < 1)


@dataclass
class Surface:
    reflectance: np.ndarray
    emission: np.ndarray
    warnings: list = field(default_factory=list)


class _Unsupported(Exception):
    pass


_image_cache = {}


def _srgb_bytes(img):
    return not img.is_float and img.colorspace_settings.name in ("sRGB", "Filmic sRGB", "AgX Base sRGB")


def image_pixels(img, linear=True):
    """(H, W, 3) RGB float32 of an image (row 0 at the bottom), or None if it has no pixels.
    linear: 8-bit sRGB images are linearised (else returned as stored)."""
    w, h = img.size
    if w * h == 0 or not img.has_data and not _try_load(img):
        return None
    px = np.empty(w * h * img.channels, np.float32)
    img.pixels.foreach_get(px)
    px = px.reshape(-1, img.channels)
    rgb = px[:, :3] if img.channels >= 3 else np.repeat(px[:, :1], 3, 1)
    if linear and _srgb_bytes(img):
        rgb = srgb_to_linear(rgb.astype(np.float64)).astype(np.float32)
    return rgb.reshape(h, w, 3)


def image_reduced(img, reduce, cache, limit):
    """reduce(pixels (H, W, 3)) of an image, kept in `cache` (at most `limit` images) until the image
    changes, or None if it has no pixels: an image is read once, not per frame."""
    key = (img.name_full, img.filepath, tuple(img.size), img.is_dirty, img.colorspace_settings.name)
    if key in cache and not img.is_dirty:
        return cache[key]
    px = image_pixels(img)
    if px is None:
        return None
    got = reduce(px)
    if len(cache) > limit:
        cache.clear()
    cache[key] = got
    return got


def image_average(img):
    """Average linear RGB of an image, or None if it has no pixels."""
    return image_reduced(img, lambda px: px.reshape(-1, 3).astype(np.float64).mean(0), _image_cache, 64)


def _try_load(img):
    try:
        img.pixels[0]  # forces a load
    except Exception:
        return False
    return img.has_data


def _by_identifier(sockets, identifier):
    return next((s for s in sockets if s.identifier == identifier), None)


def _group_output(tree):
    outs = [n for n in tree.nodes if n.type == "GROUP_OUTPUT"]
    return next((n for n in outs if n.is_active_output), outs[0] if outs else None)


def _default_color(socket):
    v = socket.default_value
    try:
        return np.array(v[:3], float)
    except TypeError:  # a float socket feeding a colour (Blender repeats it)
        return np.full(3, float(v))


def _default_float(socket):
    v = socket.default_value
    try:
        return float(v)
    except TypeError:  # a colour socket feeding a float: Blender takes its luminance
        return float(np.dot(np.array(v[:3], float), (0.2126, 0.7152, 0.0722)))


class _Reader:
    def __init__(self, mat):
        self.mat = mat
        self.warnings = []
        # node (as_pointer) -> the Group nodes (outermost first) it was reached through: its inputs
        # linked to a Group Input read the innermost Group node's inputs
        self._groups = {}

    def warn(self, msg):
        self.warnings.append(f"Material '{self.mat.name}': {msg}")

    def unsupported(self, socket, node, what):
        self.warn(
            f"'{socket.name}' is driven by a '{node.bl_label}' node, which is not supported; "
            f"using the socket's own {what}"
        )

    def source(self, socket):
        """The node and output socket feeding `socket`, skipping reroutes and muted links and
        following node groups."""
        node, out, _ = self.trace(socket)
        return node, out

    def trace(self, socket):
        """(node, output socket, last input socket) feeding `socket`: reroutes are skipped, a Group
        node is entered (its Group Output's input), a Group Input is left (the Group node's input).
        The last input socket holds the value when nothing feeds it (node None)."""
        groups = self._groups.get(socket.node.as_pointer(), ())
        for _ in range(64):
            if not socket.is_linked:
                return None, None, socket
            link = socket.links[0]
            if getattr(link, "is_muted", False):
                return None, None, socket
            node = link.from_node
            if node.type == "REROUTE":
                socket = node.inputs[0]
                continue
            if node.type == "GROUP" and node.node_tree is not None and not node.mute:
                out = _group_output(node.node_tree)
                inner = None if out is None else _by_identifier(out.inputs, link.from_socket.identifier)
                if inner is not None:
                    groups = groups + (node,)
                    socket = inner
                    continue
            if node.type == "GROUP_INPUT" and groups:
                outer = _by_identifier(groups[-1].inputs, link.from_socket.identifier)
                if outer is not None:
                    groups = groups[:-1]
                    socket = outer
                    continue
            self._groups[node.as_pointer()] = groups
            return node, link.from_socket, socket
        return None, None, socket

    def color(self, socket):
        node, out, last = self.trace(socket)
        if node is None:
            return _default_color(last)
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
        mix = _mix_sockets(node)
        if mix is not None:  # linear in each input: the average of the mix is the mix of the averages
            fac, a, b = mix
            f = min(max(self.value(fac), 0.0), 1.0)
            ca, cb = self.color(a), self.color(b)
            return (1 - f) * ca + f * (ca * cb if node.blend_type == "MULTIPLY" else cb)
        self.unsupported(socket, node, "colour")
        return np.array(socket.default_value[:3], float)

    def value(self, socket):
        node, _, last = self.trace(socket)
        if node is None:
            return _default_float(last)
        if node.type == "VALUE":
            return float(node.outputs[0].default_value)
        self.unsupported(socket, node, "value")
        return float(socket.default_value)

    def not_diffuse(self, node):
        """Name what a Principled BSDF does that the bake reads as opaque diffuse (a warning was
        missing, the reflectance clamp hid it): metal, glass (transmission), cut-outs (alpha)."""
        found = [
            label
            for label, name, plain in (
                ("metallic", "Metallic", 0.0),
                ("transmission", "Transmission Weight", 0.0),
                ("alpha", "Alpha", 1.0),
            )
            if (s := node.inputs.get(name)) is not None
            and (s.is_linked or abs(float(s.default_value) - plain) > 1e-6)
        ]
        if found:
            self.warn(
                f"{' and '.join(found)} read as opaque diffuse: the bake has no metal, glass or "
                "see-through surfaces, so the light this surface reflects or lets through differs "
                "from a render"
            )

    def shader(self, socket, depth=0):
        node, _, last = self.trace(socket)
        if node is None and last.node.type == "GROUP_OUTPUT":
            raise _Unsupported(
                f"nothing is connected to the output '{last.name}' inside the node group "
                f"'{last.id_data.name}'"
            )
        if node is None:
            raise _Unsupported("nothing is connected to the Surface output")
        if depth > 16:
            raise _Unsupported("shader nesting too deep")
        if node.mute:
            raise _Unsupported(f"the '{node.bl_label}' node is muted")
        t = node.type
        zero = np.zeros(3)
        if t == "BSDF_PRINCIPLED":
            self.not_diffuse(node)
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
        if t == "GROUP":
            tree = node.node_tree
            raise _Unsupported(
                f"the node group '{tree.name if tree else node.name}' used as the shader has no "
                "Group Output connected inside it"
                if tree is not None
                else f"the Group node '{node.name}' has no node group"
            )
        if t == "GROUP_INPUT":
            raise _Unsupported("a Group Input is used as the shader")
        raise _Unsupported(
            f"the '{node.bl_label}' shader is not supported (use Principled BSDF, Diffuse BSDF or Emission)"
        )


def _mix_sockets(node):
    """(factor, A, B) input sockets of a colour Mix node blending by Mix or Multiply, else None."""
    if (
        node.type != "MIX"
        or getattr(node, "data_type", "") != "RGBA"
        or node.blend_type not in ("MIX", "MULTIPLY")
    ):
        return None
    ids = {s.identifier: s for s in node.inputs}
    return ids["Factor_Float"], ids["A_Color"], ids["B_Color"]


def _bsdfs(r, socket, depth=0):
    """Diffuse-reflecting shader nodes (Principled, Diffuse) reached from `socket`, and whether a
    Mix Shader was on the way (then one BSDF's colour no longer is the material's)."""
    node, _ = r.source(socket)
    if node is None or depth > 16 or node.mute:
        return [], False
    if node.type in ("BSDF_PRINCIPLED", "BSDF_DIFFUSE"):
        return [node], False
    if node.type in ("ADD_SHADER", "MIX_SHADER"):
        got = [_bsdfs(r, s, depth + 1) for s in node.inputs if s.type == "SHADER"]
        return [n for g in got for n in g[0]], node.type == "MIX_SHADER" or any(g[1] for g in got)
    return [], False


def base_color_socket(mat, reader=None):
    """The colour input (Principled Base Color / Diffuse Color) of the one diffuse shader of `mat`
    reached from its active output, or None (no nodes, none or several such shaders). `reader`: the
    _Reader that follows the socket on (it knows the node groups the shader sits in)."""
    tree = None if mat is None else mat.node_tree
    if tree is None or mat.get("hr_preview") or (bpy.app.version < (5, 0, 0) and not mat.use_nodes):
        return None
    out = _output_node(tree)
    if out is None:
        return None
    nodes, _ = _bsdfs(reader or _Reader(mat), out.inputs["Surface"])
    if len(nodes) != 1:
        return None
    return nodes[0].inputs["Base Color" if nodes[0].type == "BSDF_PRINCIPLED" else "Color"]


@dataclass
class AlbedoTexture:
    """An Image Texture that is a material's diffuse colour, for per-texel albedo (lightmap.albedo)."""

    image: object
    uv_map: str  # "" : the mesh's active render UV map (the Image Texture's default)
    interpolation: str
    extension: str
    mix: tuple  # None or (blend, factor, other colour (3,), texture is input A)
    average: np.ndarray  # (3,) the colour the light exchange used for this input
    pixels: np.ndarray = None  # (H, W, 3) as stored, read by albedo_texture
    srgb: bool = False  # 8-bit sRGB: Cycles interpolates the stored values, then linearises


def _uv_source(r, tex):
    """UV map name of an Image Texture's vector input ("" default), or None if it is not a UV map."""
    node, out = r.source(tex.inputs["Vector"])
    if node is None:
        return ""
    if node.type == "UVMAP":
        return node.uv_map
    if node.type == "TEX_COORD" and out.name == "UV":
        return ""
    return None


def albedo_texture(mat):
    """(AlbedoTexture or None, reason or ""): the texture that is `mat`'s diffuse colour when the
    material is one Principled / Diffuse BSDF (plus emission) whose colour input is an Image
    Texture (UV mapped, flat projection, a single image) directly or through one Mix node with a
    constant colour and factor. reason says why a textured material does not qualify ("" when it
    has no texture at all)."""
    r = _Reader(mat)
    sock = base_color_socket(mat, r)
    textured = (
        mat is not None
        and mat.node_tree is not None
        and any(n.type == "TEX_IMAGE" and any(o.is_linked for o in n.outputs) for n in mat.node_tree.nodes)
    )
    why = "its colour texture is not an Image Texture (UV map) on the Base Color of a single diffuse shader"
    if sock is None:
        return None, why if textured else ""
    out = _output_node(mat.node_tree)
    if _bsdfs(r, out.inputs["Surface"])[1]:
        return None, (why if textured else "")
    node, o = r.source(sock)
    mix = None
    if node is not None and _mix_sockets(node) is not None:
        fac, a, b = _mix_sockets(node)
        na, oa = r.source(a)
        nb, ob = r.source(b)
        tex_a = na is not None and na.type == "TEX_IMAGE"
        other = b if tex_a else a
        if (
            fac.is_linked
            or r.source(other)[0] is not None
            or not (tex_a or nb is not None and nb.type == "TEX_IMAGE")
        ):
            return None, why if textured else ""
        mix = (
            node.blend_type,
            min(max(float(fac.default_value), 0.0), 1.0),
            np.array(other.default_value[:3], float),
            tex_a,
        )
        node, o = (na, oa) if tex_a else (nb, ob)
    if node is None or node.type != "TEX_IMAGE" or o.name != "Color":
        return None, why if textured else ""
    img = node.image
    uv = _uv_source(r, node)
    if img is None or uv is None or node.projection != "FLAT" or img.source not in ("FILE", "GENERATED"):
        return None, why
    px = image_pixels(img, linear=False)
    if px is None:
        return None, f"image texture '{node.name}' has no pixels"
    avg = np.asarray(r.color(sock), float)
    return AlbedoTexture(img, uv, node.interpolation, node.extension, mix, avg, px, _srgb_bytes(img)), ""


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
