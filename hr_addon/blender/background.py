"""The interactive bake as a separate background process, so Blender's UI never blocks.

BackgroundBake saves a copy of the current file (unsaved changes included) to a temporary folder
and starts a worker on it:
  - inside Blender: Blender's own binary, `blender -b --python-expr <enable the extension, run
    hr_bake> -- copy.blend --cache-dir <real cache> --status-file <status.json> ...`;
  - with the bpy module (no Blender binary, bpy.app.binary_path is empty): `python -m hr_addon
    bake copy.blend ...` with this package's folder on PYTHONPATH.
The worker writes into the real cache folder (through the cache writer's temporary folder, which
replaces the cache only when the bake is complete) and reports its progress in a small JSON
status file (jobstatus.py) that poll() reads. When it has finished, poll() points the scene at the
bake and loads the current frame. cancel() stops the worker (SIGTERM: it removes its partial
bake; whatever is left of it is removed here too), so the previous bake is kept.

No bpy state is touched by the worker: the user's file, scene and meshes stay as they were.
The modal operator (ops.HR_OT_bake) only calls start(), poll() on a timer and cancel(); tests
drive the same class in a loop.
"""

import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import bpy
from bpy.app.handlers import persistent

from ..lightmap import TextureError
from . import jobstatus, playback, texture
from .settings import BakeConfig
from .state import STATE
from .bake import cache_dir_for, frame_range_for, use_bake
from .lights_in import light_check, light_edges, materials_emit
from .own_values import ensure_own_values
from .scene_in import SceneError, geometry_objects

PACKAGE_DIR = Path(__file__).resolve().parents[1]  # .../hr_addon
ADDON_MODULE = __package__.rsplit(".hr_addon.blender", 1)[0] if ".hr_addon.blender" in __package__ else ""


def active():
    """The BackgroundBake that is running (or has just finished and not been collected)."""
    return STATE.background


def running():
    b = STATE.background
    return b is not None and b.state == "running"


class BackgroundBake:
    """One background bake. overrides: method, quality, frames, output, ... as in bake_frames."""

    def __init__(self, scene, view_layer=None, **overrides):
        self.scene_name = scene.name_full
        self.view_layer_name = (view_layer or scene.view_layers[0]).name
        self.overrides = overrides
        self.blend = bpy.data.filepath
        self.state = "new"  # new, running, done, failed, cancelled
        self.status = {}  # the last good status read from the worker
        self.error = ""
        self.summary = ""
        self.warnings = []
        self._start_warnings = []
        self.proc = None
        self.tmp = None
        self.final_dir = ""
        self.output = ""
        self.loaded = False
        self.started = 0.0
        self.cancelling = 0.0  # time.monotonic() of Cancel while the worker has not gone yet (0: none)
        self._finish = None  # the finished bake being loaded, a step per poll() (_use_result_steps)
        self.finish_stage = ""
        self.seen = []  # (fraction, stage, frame, eta) of every status read (tests)

    # -- what the UI shows ----------------------------------------------------------------------
    @property
    def fraction(self):
        return 1.0 if self.state == "done" else float(self.status.get("fraction") or 0.0)

    @property
    def eta(self):
        return self.status.get("eta")

    @property
    def frame(self):
        return self.status.get("frame")

    def text(self):
        """One line: percent, frame, time left."""
        if self.state == "done":
            return "Bake finished"
        if self.state in ("failed", "cancelled"):
            return "Bake cancelled; the previous bake is kept" if self.state == "cancelled" else self.error
        if self.cancelling:
            return "Cancelling: waiting for the bake process to stop"
        if self._finish is not None:
            return f"Bake finished: {self.finish_stage}"
        s = self.status
        parts = [f"{100 * self.fraction:.0f}%"]
        if s.get("stage") == "frame" and s.get("total"):
            parts.append(f"frame {s.get('frame')} ({s.get('done')}/{s.get('total')})")
        elif s.get("stage") == "build":
            parts.append("building the hierarchy")
        else:
            parts.append("starting")
        if self.eta is not None:
            parts.append(f"about {jobstatus.duration(self.eta)} left")
        return " \u00b7 ".join(parts)

    # -- worker ---------------------------------------------------------------------------------
    def _scene(self):
        return bpy.data.scenes.get(self.scene_name)

    def _args(self, copy, status_path, scene):
        o = self.overrides
        # --option=value throughout: values may start with "-" (negative frames, names)
        args = [
            copy,
            f"--scene={scene.name}",
            f"--view-layer={self.view_layer_name}",
            f"--cache-dir={self.final_dir}",
            f"--status-file={status_path}",
        ]
        frames = frame_range_for(scene, o.get("frames"))
        args.append(f"--frames={frames[0]}..{frames[1]}")
        for key in ("method", "quality", "domain", "output", "texture_format", "radiance_mode"):
            if o.get(key):
                args.append(f"--{key.replace('_', '-')}={str(o[key]).lower()}")
        for key in ("feps", "aeps", "resolution", "threads"):
            if o.get(key) is not None:
                args.append(f"--{key}={o[key]!r}")
        if o.get("contacts") is False:
            args.append("--no-contacts")
        if o.get("final_gather") is False:
            args.append("--no-final-gather")
        hr = scene.hr
        if not o.get("quality") and hr.quality == "CUSTOM" and o.get("feps") is None:
            args += [f"--feps={float(hr.feps)!r}", f"--aeps={float(hr.aeps)!r}"]
        return args

    def command(self, args, binary=None, module=None):
        """(argv, env) of the worker process: Blender's binary (default bpy.app.binary_path) running
        the extension `module` (default: this one), else `python -m hr_addon`."""
        env = dict(os.environ)
        binary = bpy.app.binary_path if binary is None else binary
        module = ADDON_MODULE if module is None else module
        if binary and module:
            expr = (
                "import sys, addon_utils, bpy\n"
                f"m = {module!r}\n"
                "if m not in bpy.context.preferences.addons:\n"
                "    addon_utils.enable(m, default_set=False)\n"
                "from importlib import import_module\n"
                "cli = import_module(m + '.hr_addon.blender.cli')\n"
                "sys.exit(cli.run(sys.argv[sys.argv.index('--') + 1:]))\n"
            )
            return [binary, "-b", "--python-exit-code", "1", "--python-expr", expr, "--", *args], env
        # bpy module (tests, scripts): this package runs as `python -m hr_addon`
        paths = [str(PACKAGE_DIR.parent)]
        try:
            import embreex

            paths.append(str(Path(embreex.__file__).resolve().parents[1]))
        except ImportError:
            pass
        old = env.get("PYTHONPATH")
        env["PYTHONPATH"] = os.pathsep.join(paths + ([old] if old else []))
        return [sys.executable, "-m", PACKAGE_DIR.name, "bake", *args], env

    def start(self):
        """Save the copy and start the worker. Raises SceneError (one-line reason) if it cannot."""
        if running():
            raise SceneError("A radiosity bake is already running.")
        scene = self._scene()
        view_layer = scene.view_layers.get(self.view_layer_name)
        self.final_dir = cache_dir_for(scene)
        if not geometry_objects(view_layer):
            raise SceneError(
                "No mesh objects to compute radiosity on (all hidden, excluded or light shapes)."
            )
        frame_range_for(scene, self.overrides.get("frames"))
        # the settings are checked here, at once, as the worker's bake will check them
        cfg = BakeConfig.resolve(scene.hr, **{k: v for k, v in self.overrides.items() if k != "frames"})
        depsgraph = view_layer.depsgraph
        depsgraph.update()
        error, _ = light_check(view_layer, scene, depsgraph, materials_emit(depsgraph))
        if error:  # at once, not from the worker after it has loaded the file
            raise SceneError(error)
        self.output = cfg.output
        if self.output == "VERTEX":  # the helpers belong to the user's file: made here, the copy gets them
            # (the spacing's note and the corner budget's line are the worker's to log: its bake of the copy
            # counts the same)
            edges, was = ((), ()), STATE.baking
            if cfg.spacing > 0:  # (moving shapes: read over the frames, no playback load on the way)
                STATE.baking = True
                try:
                    edges = light_edges(scene, view_layer)
                finally:
                    STATE.baking = was
            self._start_warnings = ensure_own_values(
                geometry_objects(view_layer), cfg.domain, depsgraph, cfg.spacing, lambda line: None, *edges
            )
            self.warnings += self._start_warnings
        if self.output == "TEXTURE":
            # The lightmap UV maps belong to the user's meshes: make them here, the copy gets them.
            try:
                self._start_warnings = texture.ensure_lightmaps(
                    geometry_objects(view_layer), cfg.resolution, cfg.texel_density
                )
                self.warnings += self._start_warnings
            except TextureError as exc:
                raise SceneError(str(exc)) from None
        STATE.bake_starts(scene)  # Live ends: the bake shows its own result when it has finished
        self.tmp = Path(tempfile.mkdtemp(prefix="hr_bake_"))
        copy = str(self.tmp / (os.path.basename(self.blend) or "untitled.blend"))
        status_path = str(self.tmp / "status.json")
        try:
            bpy.ops.wm.save_as_mainfile(filepath=copy, copy=True, check_existing=False, relative_remap=True)
        except RuntimeError as exc:
            self._cleanup()
            raise SceneError(f"Cannot save a copy of the file for the background bake: {exc}") from None
        argv, env = self.command(self._args(copy, status_path, scene))
        self.status_path = status_path
        self.log_path = self.tmp / "worker.log"
        log = open(self.log_path, "wb")
        try:
            self.proc = subprocess.Popen(
                argv,
                env=env,
                cwd=str(self.tmp),
                stdin=subprocess.DEVNULL,
                stdout=log,
                stderr=subprocess.STDOUT,
            )
        except OSError as exc:
            self._cleanup()
            raise SceneError(f"Cannot start the background bake ({argv[0]}): {exc}") from None
        finally:
            log.close()
        self.state = "running"
        self.started = time.monotonic()
        STATE.background = self
        return self

    def _read(self):
        s = jobstatus.read_status(self.status_path)
        if s is not None and s.get("pid") == self.proc.pid:  # not a stale file of another worker
            self.status = s
            self.warnings += [w for w in s["warnings"] if w not in self.warnings]
            self.seen.append((s["fraction"], s.get("stage"), s.get("frame"), s.get("eta")))
        return s

    def _log_error(self):
        try:
            lines = self.log_path.read_text(errors="replace").splitlines()
        except OSError:
            return ""
        errs = [ln.split("error:", 1)[1].strip() for ln in lines if "hr_bake: error:" in ln]
        return errs[-1] if errs else (lines[-1].strip() if lines else "")

    @property
    def finishing(self):
        """The worker has finished: its result is being loaded (poll() returns True until done)."""
        return self._finish is not None

    def poll(self):
        """Read the worker's progress; when it has ended, load the result. True while running.

        The result is loaded over several calls, each short (the UI thread must not freeze): the
        scene pointed at the bake, then the current frame's values, then the comparison of the
        scene with the bake (edits made while the worker baked a copy), spread over as many calls
        as it needs (playback.check_scene_slice). The operator's timer runs faster meanwhile."""
        if self.state != "running":
            return False
        if self._finish is not None:
            return self._finish_step()
        if self.cancelling:  # Cancel without waiting: end it once the worker has gone
            if self.proc.poll() is None:
                if time.monotonic() - self.cancelling > self.kill_after:
                    self.proc.kill()
                return True
            self._cancelled()
            return False
        self._read()
        rc = self.proc.poll()
        if rc is None:
            return True
        s = self._read() or self.status
        if s.get("state") == "done" and rc == 0:
            self.summary = s.get("summary", "")
            # the worker's final list: every warning once, repeats counted
            self.warnings = list(self._start_warnings) + [
                w for w in s.get("warnings", []) if w not in self._start_warnings
            ]
            self._finish = self._use_result_steps()
            return self._finish_step()
        elif s.get("state") == "cancelled":
            self.state = "cancelled"
        else:
            self.state = "failed"
            self.error = s.get("error") or self._log_error() or f"the bake process exited with code {rc}"
        self._cleanup()
        return False

    def _finish_step(self):
        try:
            self.finish_stage = next(self._finish)
            return True
        except StopIteration:
            pass
        except ReferenceError:  # the scene went away meanwhile (its file closed)
            pass
        self._finish = None
        self.state = "done"
        self._cleanup()
        return False

    def _use_result(self):
        """Load the result in one go (_use_result_steps to the end)."""
        for _ in self._use_result_steps():
            pass

    RESTARTS = 3  # comparisons started again by edits before the panel's timer is left to finish it

    def _use_result_steps(self):
        """Point the scene at the bake, show its frame, compare the scene with it: a generator
        yielding what it does next, a step per poll()."""
        scene = self._scene()
        if scene is None or bpy.data.filepath != self.blend:
            self.warnings.append(f"The bake finished in {self.final_dir}, but another file is open now.")
            return
        use_bake(scene, self.final_dir, self.output)
        playback.forget_loaded()
        yield "loading the current frame"
        self.loaded = playback.load_frame(scene)
        # edits made while the worker baked a copy are not in the bake: the panel names them
        name, restarts = scene.name_full, 0
        STATE.dirty.discard(name)
        STATE.checks.pop(name, None)
        while True:
            yield "comparing the scene with the bake"
            if name in STATE.dirty and name in STATE.checks:  # edited while comparing: again
                restarts += 1
                if restarts > self.RESTARTS:  # edits go on: the panel's stale check takes it over
                    playback._schedule_check(playback.EDIT_PAUSE)
                    return
            stale = playback.check_scene_slice(scene)
            if stale is not None:
                break
        if stale:
            self.warnings.append(stale)

    kill_after = 15.0  # seconds a cancelled worker has to stop before it is killed

    def cancel(self, timeout=None, wait=True):
        """Stop the worker; its partial bake is removed and the previous bake is kept.

        wait False (the Cancel button): send the signal and return at once; the job stays running
        ("Cancelling", the Bake button greyed out: the worker still owns its cache folder) until a
        later poll() sees the worker gone and ends it as cancelled (killed if it has not stopped
        after kill_after s). A worker baking frames stops 1-3 s after the signal (the furnished
        100k room): waiting here froze the UI as long.
        wait True (scripts, a file being opened, the add-on being disabled): return when the
        worker has gone and its partial bake is removed (timeout: seconds before it is killed,
        default kill_after)."""
        if self.state != "running":
            return
        if self._finish is not None:  # the bake is complete and shown: the comparison is left off
            self._finish.close()
            self._finish = None
            self.state = "done"
            self._cleanup()
            return
        proc = self.proc
        if not self.cancelling:
            self.cancelling = time.monotonic()
            if proc.poll() is None:
                proc.terminate()  # SIGTERM: the worker removes its partial bake
        if not wait:
            return
        if proc.poll() is None:
            left = self.kill_after if timeout is None else timeout
            try:
                proc.wait(max(0.0, left - (time.monotonic() - self.cancelling)))
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
        self._cancelled()

    def _cancelled(self):
        self.proc.wait()
        self.state = "cancelled"
        self._cleanup()

    def _cleanup(self):
        final = Path(self.final_dir) if self.final_dir else None
        if final is not None and self.proc is not None and final.parent.is_dir():
            # the worker's temporary cache folder, if it could not remove it itself (killed)
            from ..io.cache import HOST, temp_dirs

            for d, kind, host, pid, _ in temp_dirs(final):
                if kind == "baking" and pid == self.proc.pid and host in ("", HOST):
                    shutil.rmtree(d, ignore_errors=True)
        if self.tmp is not None:
            shutil.rmtree(self.tmp, ignore_errors=True)
        if STATE.background is self and self.state != "running":
            STATE.background = None


@persistent
def _on_load_pre(*args):
    """Opening another file while a bake runs: stop the bake (its scene is going away)."""
    if running():
        STATE.background.cancel()


def register():
    playback._remove(bpy.app.handlers.load_pre, _on_load_pre)
    bpy.app.handlers.load_pre.append(_on_load_pre)


def unregister():
    if running():
        STATE.background.cancel()
    playback._remove(bpy.app.handlers.load_pre, _on_load_pre)
