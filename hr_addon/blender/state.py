"""The add-on's state in this Blender session: one object instead of module globals.

Keys are scene name_full. Holds what playback loaded and reports, the Live sessions, the
interactive bake, and the meshes whose HR_Radiance we wrote ourselves. No bpy.
"""


class OwnWrites:
    """Meshes whose HR_Radiance we wrote: their next depsgraph update is ours, not an edit. Each
    reader (playback; a Live session, by scene) takes its own view, so one does not consume the
    other's."""

    def __init__(self):
        self._pending = {}

    def mark(self, mesh_name, reader="playback"):
        self._pending.setdefault(reader, set()).add(mesh_name)

    def mark_all(self, mesh_names, reader="playback"):
        self._pending.setdefault(reader, set()).update(mesh_names)

    def take(self, reader="playback"):
        return self._pending.pop(reader, set())

    def forget(self, reader):
        self._pending.pop(reader, None)


class AddonState:
    def __init__(self):
        # A synchronous bake runs in this process: it moves through frames itself, playback and
        # Live must not interfere.
        self.baking = False
        self.background = None  # the interactive bake (background.BackgroundBake), if any
        # playback: load problems per scene; readers per directory; what is loaded per scene;
        # "the scene changed" per scene; memo of the last check (key, message); scenes edited
        # since; image problems; the last bake's warnings and why it failed (the panel shows both)
        self.messages = {}
        self.readers = {}
        self.loaded = {}
        self.stale = {}
        self.changes = {}
        self.checks = {}  # stale checks spread over UI timer ticks (playback.check_scene_slice)
        self.dirty = set()
        self.image_checks = {}
        self.notes = {}
        self.errors = {}
        self.writes = OwnWrites()
        # Live Relight: the session per scene, why Live is not running (refused, stopped), and
        # whether its timer is running (it must not re-register itself)
        self.live_sessions = {}
        self.live_messages = {}
        self.in_tick = False
        self._bake_start = []

    def bake_running(self):
        """A bake in this process or the interactive bake's worker."""
        return self.baking or (self.background is not None and self.background.state == "running")

    def on_bake_start(self, fn):
        """fn(scene) runs when a bake of scene starts (Live ends: the bake shows its own result)."""
        if fn not in self._bake_start:
            self._bake_start.append(fn)

    def bake_starts(self, scene):
        for fn in self._bake_start:
            fn(scene)


STATE = AddonState()
