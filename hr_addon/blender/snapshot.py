"""What a bake reads of the scene once, at its start frame: the participating meshes (one MeshInput
and the Targets their values go to), each object's signature, the light shapes' identity and the
Blender lights taking part. Light shapes and lights are read again per frame (bake.py)."""

import dataclasses

from ..lightmap import TextureError
from . import playback, signatures, texture
from .lights_in import frozen_emitters, light_check, light_edges, light_objects, world_takes_part
from .own_values import ensure_own_values, spacing_off_note
from .scene_in import SceneError, collect_geometry, geometry_objects, light_shape_objects


@dataclasses.dataclass
class Snapshot:
    objects: list  # participating mesh objects
    scene_in: object  # scene_in.SceneInput: the MeshInput and the Targets
    geometry: dict  # per-object signatures (manifest; "the scene changed since the bake")
    shapes_id: dict  # light-shape identity (manifest)
    has_shapes: bool
    lights: list  # Blender light objects, hidden ones included (they may show on another frame)
    world: str = ""  # the World's name when its sky takes part (lights_in.world_takes_part)

    @property
    def has_lights(self):
        return bool(self.lights or self.world)

    @property
    def mesh(self):
        """The output's mesh (the targets' loops)."""
        return self.scene_in.mesh

    @property
    def transport(self):
        """The mesh the hierarchy is built on: the output's, or with Vertex Spacing and the final
        gather the subdivided objects' meshes before their subdivision (scene_in.collect_geometry)."""
        return self.scene_in.mesh if self.scene_in.transport is None else self.scene_in.transport

    @property
    def output(self):
        """(output mesh, its polygons' transport polygons) for the gather's OutputLayout, or None
        (the output is on the transport's mesh)."""
        si = self.scene_in
        return None if si.transport is None else (si.mesh, si.transport_poly)


def read_snapshot(scene, view_layer, cfg, warn, log=None):
    """The Snapshot for a bake of settings cfg (settings.BakeConfig); warn(list of str) takes the
    warnings, log(str) the notes that ask nothing of the user (the spacing's, the corner budget's;
    None: they are warnings too).
    Raises SceneError for a scene that cannot be baked (nothing emits: refused before the build,
    never a black bake without a word). Texture output makes the HR_Lightmap UVs first."""
    depsgraph = view_layer.depsgraph
    objects = geometry_objects(view_layer)
    if cfg.output == "VERTEX":
        warn(playback.linked_meshes(objects))
        log = log if log is not None else (lambda line: warn([line]))
        if cfg.vertex_spacing > 0 and not cfg.spacing:
            log(spacing_off_note(cfg.vertex_spacing))
        edges = light_edges(scene, view_layer) if cfg.spacing > 0 else ((), ())
        warn(ensure_own_values(objects, cfg.domain, depsgraph, cfg.spacing, log, *edges))
    if cfg.output == "TEXTURE":
        try:
            warn(texture.ensure_lightmaps(objects, cfg.resolution, cfg.texel_density))
        except TextureError as exc:
            raise SceneError(str(exc)) from None
    with texture.source_materials(objects):  # texture preview copies stand for these
        # Vertex Spacing with the final gather: the hierarchy on the user's meshes, the corner
        # samples on the finer ones (without the gather the leaves are the output: finer)
        split = cfg.output == "VERTEX" and cfg.gather is not None and cfg.spacing > 0
        scene_in = collect_geometry(
            view_layer, depsgraph, vertex_output=cfg.output != "TEXTURE", transport=split
        )
    warn(scene_in.warnings)
    error, light_warnings = light_check(view_layer, scene, depsgraph, bool(scene_in.mesh.emission.any()))
    if error:
        raise SceneError(error)
    warn(light_warnings + frozen_emitters(view_layer, scene.frame_start))
    return Snapshot(
        objects,
        scene_in,
        scene_in.signatures,
        signatures.light_shape_identity(view_layer),
        bool(light_shape_objects(view_layer, include_hidden=True)),
        # Blender lights (issue 20): read per frame like light shapes (keyframed transform,
        # colour, power, cone)
        list(light_objects(view_layer, include_hidden=True)),
        scene.world.name if world_takes_part(scene) else "",
    )
