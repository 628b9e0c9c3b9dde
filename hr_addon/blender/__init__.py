"""Blender glue: reads the scene, writes results, UI. All physics is in ..core, the bake files in
..io, the lightmap texel work in ..lightmap (all three bpy-free).

Modules: props (Scene.hr / Object.hr), materials + scene_in (scene in), signatures (what a bake
depends on), bake (the frame loop), texture (lightmap UV layers, texel plans, helper material),
playback (HR_Radiance, handlers), preview, background + jobstatus (the interactive bake's worker
process and its status file), live + live_worker (Live Relight: the session and handlers, the
worker thread, no bpy), interrupt (Ctrl-C / SIGTERM), ops, panels, cli.
"""

_cli_handle = None
# Unregistering twice raised "missing bl_rna attribute": the bpy module runs our atexit hook
# (below), then Blender's own exit disables the enabled extension again.
_registered = False


def _modules():
    from . import background, live, ops, panels, playback, props

    return props, ops, panels, playback, background, live


def register():
    global _cli_handle, _registered
    import bpy
    from . import cli

    props, ops, panels, playback, background, live = _modules()
    props.register()
    for c in ops.classes + panels.classes:
        bpy.utils.register_class(c)
    playback.register()
    background.register()
    live.register()
    if _cli_handle is None:
        _cli_handle = bpy.utils.register_cli_command("hr_bake", cli.cli_command)
    _registered = True
    global _atexit_set
    if not bpy.app.binary_path and not _atexit_set:
        # The bpy module of Blender 4.2 and 4.5 crashes (4.2) or hangs (4.5) when Python exits with
        # the add-on still registered (handlers, CLI command, ...): unregister it first, as
        # Blender itself does on exit.
        import atexit

        atexit.register(_at_exit)
        _atexit_set = True


_atexit_set = False


def _at_exit():
    try:
        unregister()
    except Exception:  # exiting anyway
        pass


def _unregister_cli():
    global _cli_handle
    if _cli_handle is not None:
        import bpy

        bpy.utils.unregister_cli_command(_cli_handle)
        _cli_handle = None


def unregister():
    global _registered
    if not _registered:
        return
    _registered = False
    import bpy

    props, ops, panels, playback, background, live = _modules()
    _unregister_cli()
    live.unregister()
    background.unregister()
    playback.unregister()
    for c in reversed(ops.classes + panels.classes):
        bpy.utils.unregister_class(c)
    props.unregister()
