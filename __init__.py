# SPDX-License-Identifier: GPL-3.0-or-later
"""Blender extension entry point (see the comment at the top of blender_manifest.toml).

Blender imports this file as `bl_ext.<repo>.hr_radiosity`; the add-on itself is the `hr_addon`
sub-package. Imports are relative and deferred to register() so that importing this file outside
Blender (pytest collects the repository root as a package) has no side effects.
"""


def register():
    from .hr_addon import register as _register

    _register()


def unregister():
    from .hr_addon import unregister as _unregister

    _unregister()
