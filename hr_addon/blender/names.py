"""Names the add-on gives to what it writes into a .blend: attributes, UV layers, tags, nodes.

One home so that modules reading them (playback, preview, signatures, texture) need not import
each other; pure constants, no bpy.
"""

ATTRIBUTE = "HR_Radiance"  # colour attribute with the per-frame radiance
UV_NAME = "HR_Lightmap"  # UV layer of the baked textures
TAG = "hr_lightmap_of"  # on helper materials and images: the object's name
# geometry-nodes modifier (and its node group) that lays HR_Lightmap out on the evaluated mesh of
# an object whose modifiers copy parts of it (texture.separate_copies)
N_PACK = "HR Lightmap"
# geometry-nodes modifier that shows an object's own vertex output, kept by a helper object
# "HR Radiance <object>" (own_values)
N_VALUES = "HR Radiance"
# face attribute its subdividing group (Vertex Spacing) stores: the index of the face each finer face
# came from, so the orientation check judges the user's face as a whole (scene_in reads it)
FACE = "HR_Face"
# face attribute of the user's mesh the bake writes (own_values.near_clutter's faces): how many levels
# finer than the Vertex Spacing the subdividing group cuts that face (removed with the modifier)
FINER = "HR_Finer"
# corner attribute of the subdividing group's output (and so of its helper's mesh): a hash of the
# mesh the group received, corner by corner (own_values._from_helper; "." : internal, not listed)
GUARD = ".HR_Guard"

PREVIEW = "HR Preview"  # name prefix of the preview nodes / material (ignored when reading)
N_ATTR, N_EMIT, N_OUT = PREVIEW + " Attribute", PREVIEW + " Emission", PREVIEW + " Output"
N_MUL, N_ADD = PREVIEW + " Base Color", PREVIEW + " Add Emission"
# Indirect only: the material's own shader + the bake's Emission, which diffuse rays do not see
N_SHADER, N_PATH, N_SEEN = PREVIEW + " Add Shader", PREVIEW + " Light Path", PREVIEW + " Not Diffuse"
N_UV, N_TEX = PREVIEW + " Lightmap UV", PREVIEW + " Lightmap"
