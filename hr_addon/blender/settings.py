"""Bake settings: one table of the choices (Scene.hr's enum items and the command line's choices
are made from it), and BakeConfig.resolve(), the one place where Scene.hr plus overrides become
checked settings. The bake, Live Relight, the command line and the background worker use it.

No bpy, and core is imported inside the functions that need it: the command line builds its
parser from this table and checks its arguments before the slow imports (numpy, bpy).
"""

import dataclasses
from dataclasses import dataclass

# identifier, UI name, description, in the order the UI lists them
ENUMS = {
    "method": (
        (
            "AUTO",
            "Auto: chosen per element by an error bound",
            "Fractional emission or adaptive refinement, chosen per element by an error bound "
            "(accurate and fast; recommended)",
        ),
        ("AR", "Adaptive refinement (AR)", "Subdivide the elements under the light shape's outline"),
        (
            "FE",
            "Fractional emission (FE)",
            "Elements partly covered by a light shape emit the covered fraction (fastest)",
        ),
        (
            "NAIVE",
            "Rebuild (naive)",
            "Light shapes become new patches and the solution is rebuilt (slow reference)",
        ),
    ),
    "quality": (
        ("DRAFT", "Draft", "Coarse and fast"),
        ("MEDIUM", "Medium", "Balanced"),
        ("HIGH", "High", "Fine subdivision, slow"),
        ("CUSTOM", "Custom", "Use the form factor (Feps) and area (Aeps) thresholds below"),
    ),
    "output": (
        ("VERTEX", "Vertex", "Colour attribute HR_Radiance on each mesh"),
        (
            "TEXTURE",
            "Baked Textures",
            "One float image per object and frame (image sequence in the cache), "
            "mapped by the UV map HR_Lightmap",
        ),
    ),
    "texture_format": (
        ("EXR", "OpenEXR", "32-bit float, linear (exact radiance)"),
        ("PNG", "PNG", "16-bit, sRGB-encoded; radiance above 1 is clipped"),
    ),
    "radiance_mode": (
        (
            "RADIANCE",
            "Outgoing radiance",
            "The light leaving each surface (emission included, the material's colour baked in): "
            "shown as it is",
        ),
        (
            "IRRADIANCE",
            "Irradiance (lightmap)",
            "The diffuse light arriving at each surface (irradiance / pi, no emission), which the "
            "material multiplies by its own base colour: game-engine lightmaps, Cycles' Diffuse bake "
            "without Color",
        ),
        (
            "INDIRECT",
            "Indirect only (for EEVEE)",
            "Irradiance / pi like Irradiance, without the direct light of Blender lights and the "
            "World: the bounce light and the light of emissive meshes and light shapes. The preview "
            "adds base colour x it to the material's own shader, so EEVEE renders the lamps' direct "
            "light, shadows and speculars and the bake the moving bounce light (needs Final Gather)",
        ),
    ),
    "domain": (
        ("CORNER", "Face Corner", "One value per face corner: creases between walls stay sharp"),
        ("POINT", "Vertex", "One value per vertex: smooth everywhere, smaller"),
    ),
}
DEFAULTS = {
    "method": "AUTO",
    "quality": "MEDIUM",
    "output": "VERTEX",
    "texture_format": "EXR",
    "radiance_mode": "RADIANCE",
    "domain": "CORNER",
}

RESOLUTION = (8, 16384)  # texture size in texels
# lightmap texels per metre (Blender unit) of surface; 50: 2 cm texels, which the camera measure
# found 94-98% of the furnished room's objects within 5% of Cycles with (4 cm: 78-80%;
# docs/accuracy.md, "Per object from a camera")
DENSITY = (0.01, 10000.0)
TEXEL_DENSITY = 50.0
# the Texture Size: the largest lightmap an object sized by area may reach. 1024 since session 31
# (branch texcap; 128 before): at 50 texels/m it honours the density up to 20 m objects (the
# furnished room's 6 m walls want 304, and capped at 128 lost the window's light on them:
# docs/accuracy.md, "Texture Size as a ceiling"). A file where the user set the Texture Size keeps it.
TEXTURE_SIZE = 1024
# the texture bake's memory budget, bytes: when its estimated peak (lightmap.plan.bake_bytes: the
# texels it will gather, from the objects' surfaces at the density, and the scene's polygons) is
# more, the objects sized by area take a lower density (texture.scene_density). Half a 16 GB
# machine; fixed, not the machine's free memory, so the lightmaps are the same on every machine.
# Session 32 (branch texmem; before, 8.39 M texels of image, whose bytes varied 2x with the sizes:
# docs/scale.md); the samples at 50 texels/m stay under it.
TEXTURE_MEMORY = 8_000_000_000
# vertex output with the final gather: edges longer than this (metres) subdivided, so light changing
# across a coarse face shows (own_values; docs/accuracy.md, "Vertex Spacing"); 0: the mesh's own
# corners. 0.25 since session 23 (furnished sample from the camera 80 / 74% of its objects within 5%
# of Cycles against 62 / 67% at 0, for x1.2-1.4 the bake's CPU)
VERTEX_SPACING = 0.25
# the lamps' direct light taken out is the final gather's own, per sample (core.lights.indirect_incident)
INDIRECT_NEEDS_GATHER = (
    "values 'Indirect only (for EEVEE)' need the Final Gather (Render > HR Radiosity): it computes "
    "the Blender lights' direct light that this mode leaves out"
)


def live_mode(radiance_mode):
    """What Live Relight writes: the indirect light in the Indirect-only mode (the viewport's EEVEE
    adds its own direct light), else outgoing radiance (shown as it is)."""
    return "INDIRECT" if radiance_mode == "INDIRECT" else "RADIANCE"


def ids(name):
    return tuple(e[0] for e in ENUMS[name])


def items(name):
    """EnumProperty items of setting `name`."""
    return list(ENUMS[name])


def choices(name):
    """The command line's choices of setting `name` (lower case)."""
    return [i.lower() for i in ids(name)]


def resolution_problem(n):
    return (
        f"bad texture resolution {n} ({RESOLUTION[0]} to {RESOLUTION[1]})"
        if not (RESOLUTION[0] <= n <= RESOLUTION[1])
        else ""
    )


def density_problem(d):
    return (
        f"bad texel density {d:g} ({DENSITY[0]:g} to {DENSITY[1]:g} texels per metre, 0: every "
        "lightmap the Texture Size)"
        if not (d == 0 or DENSITY[0] <= d <= DENSITY[1])
        else ""
    )


def spacing_problem(s):
    return f"bad vertex spacing {s:g} (0: off, or a length in metres)" if not s >= 0 else ""


def thresholds_problem(feps, aeps):
    # :g - the scene's values are float32 (aeps=0.0010000000474974513)
    if 0 < feps <= 1 and 0 < aeps < 1:
        return ""
    return f"bad thresholds feps={feps:g} aeps={aeps:g} (need 0 < feps <= 1, 0 < aeps < 1)"


def _choice(name, value, label):
    value = str(value).upper()
    if value not in ids(name):
        from .scene_in import SceneError

        raise SceneError(f"Unknown {label} '{value}' (choose from {', '.join(choices(name))}).")
    return value


@dataclass(frozen=True)
class BakeConfig:
    """Checked bake settings (identifiers upper case)."""

    method: str
    quality: str
    domain: str
    output: str
    texture_format: str
    radiance_mode: str
    resolution: int  # the largest lightmap (Texture Size)
    feps: float
    aeps: float
    contacts: bool
    final_gather: bool
    threads: int = 0  # core.parallel.resolve_threads: 0 every core; never changes the result
    texel_density: float = 0.0  # lightmap texels per unit (texture.resolution_for); 0: all Texture Size
    vertex_spacing: float = VERTEX_SPACING  # vertex output: edges longer subdivided (own_values); 0: off

    @classmethod
    def resolve(cls, hr, **overrides):
        """Scene.hr's settings, each replaced by its override unless that is None. Raises
        SceneError (one line) for an unknown choice or a value out of range."""
        from .scene_in import SceneError

        def get(key):
            v = overrides.get(key)
            return getattr(hr, key) if v is None else v

        unknown = set(overrides) - {f.name for f in dataclasses.fields(cls)}
        if unknown:
            raise TypeError(f"unknown bake settings: {', '.join(sorted(unknown))}")
        cfg = cls(
            method=_choice("method", get("method"), "method"),
            quality=_choice("quality", get("quality"), "quality"),
            domain=_choice("domain", get("domain"), "domain"),
            output=_choice("output", get("output"), "output"),
            texture_format=_choice("texture_format", get("texture_format"), "texture format"),
            radiance_mode=_choice("radiance_mode", get("radiance_mode"), "radiance mode"),
            resolution=int(overrides.get("resolution") or hr.texture_resolution),
            feps=float(get("feps")),
            aeps=float(get("aeps")),
            contacts=bool(get("contacts")),
            final_gather=bool(get("final_gather")),
            threads=int(get("threads")),
            texel_density=float(get("texel_density")),
            vertex_spacing=float(get("vertex_spacing")),
        )
        problem = (
            resolution_problem(cfg.resolution)
            or density_problem(cfg.texel_density)
            or spacing_problem(cfg.vertex_spacing)
            or (thresholds_problem(cfg.feps, cfg.aeps) if cfg.quality == "CUSTOM" else "")
            or (INDIRECT_NEEDS_GATHER if cfg.radiance_mode == "INDIRECT" and not cfg.final_gather else "")
        )
        if problem:
            raise SceneError(problem[0].upper() + problem[1:] + ".")
        return cfg

    @property
    def live_mode(self):
        return live_mode(self.radiance_mode)

    @property
    def spacing(self):
        """The Vertex Spacing the bake uses: the setting's with the final gather, else 0. Without the
        gather the hierarchy's leaves are the output, so a spacing would build the whole hierarchy
        on the finer mesh (about twice the bake) and change the classic output, which stays the
        mesh's own corners (issue 19: the gather off reproduces it)."""
        return self.vertex_spacing if self.final_gather and self.output == "VERTEX" else 0.0

    @property
    def gather(self):
        """The final gather's settings, or None when it is off."""
        return gather_params(self.quality, self.final_gather)

    @property
    def params(self):
        """The hierarchy's RefineParams (before solver_setup scales them to the scene)."""
        return refine_params(self.quality, self.feps, self.aeps, self.contacts, self.final_gather)

    @property
    def solve_options(self):
        return solve_options(self.quality, self.final_gather)

    @property
    def live_threads(self):
        """Live Relight's threads: the setting, but one core kept for the interface (-1: all but
        one)."""
        from ..core.parallel import resolve_threads

        return min(resolve_threads(self.threads), resolve_threads(-1))


# Final gather (core/gather.py, docs/gather.md) per quality: hemisphere rays per output sample,
# shadow rays per sample and emitter, levels (2: the hits gather exact direct light of their own),
# iterations (the second level's samples gather from each other: light after more bounces)
GATHER = {
    "DRAFT": dict(rays=128, shadow_rays=16, levels=2, iterations=4),
    "MEDIUM": dict(rays=128, shadow_rays=32, levels=2, iterations=4),
    "HIGH": dict(rays=256, shadow_rays=64, levels=2, iterations=8),
    "CUSTOM": dict(rays=128, shadow_rays=32, levels=2, iterations=4),
}


def gather_params(quality, final_gather=True):
    """The final gather's settings for `quality`, or None when it is off (the hierarchy's leaves
    are shown, as before the final gather)."""
    return dict(GATHER[quality.upper()]) if final_gather else None


def refine_params(quality, feps=None, aeps=None, contacts=True, final_gather=False):
    # orient: faces facing the wrong way are turned around, as Cycles (two-sided) shows them.
    # final_gather: the output gathers its own light, the hierarchy only carries what the gather
    # reads: the quality's transport preset for that (RefineParams.for_gather, coarser links;
    # docs/gather.md, Transport). Custom feps / aeps stay the user's.
    from ..core.refine import RefineParams

    quality = _choice("quality", quality, "quality")
    if quality == "CUSTOM":
        p = dataclasses.replace(RefineParams.preset("medium"), feps=float(feps), aeps=float(aeps))
    elif final_gather:
        p = RefineParams.for_gather(quality.lower())
    else:
        p = RefineParams.preset(quality.lower())
    return dataclasses.replace(p, contacts=bool(contacts), orient=True)


def solve_options(quality, final_gather=False):
    """DynamicRadiosity's solver options: with the final gather, tolerances matched to the output
    (DynamicRadiosity.gather_options); off, the defaults (1e-7)."""
    if not final_gather:
        return {}
    from ..core.events import DynamicRadiosity

    q = quality.upper()
    return DynamicRadiosity.gather_options("medium" if q == "CUSTOM" else q.lower())


def solver_setup(mesh, params):
    """(params, min_area_rel, warning or '') for solving `mesh` (a core MeshInput), as every bake and
    Live Relight set the solver up. Objects far from the rest exchange practically no light with
    it; the area thresholds (Aeps, AR/AUTO's smallest element) are made relative to the rest only,
    so that the rest gets the same light with or without them (the warning names them)."""
    import inspect

    from ..core.events import DynamicRadiosity
    from ..core.geometry import isolated_objects

    min_area_rel = inspect.signature(DynamicRadiosity).parameters["min_area_rel"].default
    extent = isolated_objects(mesh)
    area_ratio = extent.area_ratio
    warning = ""
    if extent.distant:
        far = extent.distant
        names = ", ".join(f"'{n}'" for n, _, _ in far[:5]) + (
            f" and {len(far) - 5} more" if len(far) > 5 else ""
        )
        near, farthest = _length(far[-1][1]), _length(far[0][1])
        dist = farthest if near == farthest else f"{near} to {farthest}"
        warning = (
            f"{len(far)} object(s) lie far from the rest of the scene ({names}, {dist} away; the rest "
            f"is {_length(extent.main_size)} across): they "
            "exchange almost no light with it and do not change its element sizes. Exclude them "
            "(Object > HR Radiosity > Exclude) if they are not meant to be there."
        )
        params = dataclasses.replace(params, aeps=params.aeps * area_ratio)
    return params, min_area_rel * area_ratio, warning


def _length(m):
    return f"{m / 1000:.3g} km" if m >= 1000 else (f"{m:.3g} m" if m >= 0.1 else f"{m * 100:.3g} cm")


def make_gather(solution, output_plan=None, settings=None, smooth_angle=30.0, output=None):
    """The output stage for a solution (DynamicRadiosity or RadiositySystem): a LoopGather for
    vertex output, the texture plan's texel gather for texture output, None when it is off.
    output: (mesh, transport polygon per polygon): the vertex output on that finer mesh's corners
    (core.gather.OutputLayout; Vertex Spacing), None: on the system's mesh."""
    if settings is None:
        return None
    if output_plan is not None:
        return output_plan.final_gather(solution, **settings)
    from ..core.gather import LoopGather, OutputLayout

    layout = None if output is None else OutputLayout(solution.system, *output)
    return LoopGather(solution, smooth_angle=smooth_angle, output=layout, **settings)


def precompute_key(mesh, params, gather, texels=None, output=None):
    """What the scene precompute (io/precompute.py) must have been built from: the build's input
    and settings, and the output the final gather was traced for (vertex loops, or the texels of
    the lightmaps `texels` describes: {object name: "resolution px, uv digest"}). Not the method
    nor the light: every method starts from the same RadiositySystem and gather, and a light event
    changes neither (DynamicRadiosity grows its own nodes past them)."""
    import hashlib

    import numpy as np

    from ..io import precompute as pc

    stage = "off" if gather is None else ("texture" if texels is not None else "vertex")
    extra = {f"lightmap.{k}": v for k, v in (texels or {}).items()}
    if output is not None:  # the vertex output on a finer mesh (make_gather's output): its digest
        import json

        out_mesh, poly = output
        d = hashlib.sha256(json.dumps(pc.mesh_signatures(out_mesh), sort_keys=True).encode())
        d.update(np.ascontiguousarray(poly, np.int64).tobytes())
        extra["vertex_output_mesh"] = d.hexdigest()[:16]
    flat = (mesh if output is None else output[0]).flat
    if stage == "vertex" and flat is not None and np.any(flat):  # its corners' averages (layouts.FLAT_ANGLE)
        extra["vertex_flat"] = hashlib.sha256(np.packbits(np.asarray(flat, bool)).tobytes()).hexdigest()[:16]
    return pc.expected(mesh, params, gather=gather, final_gather=stage, **extra)
