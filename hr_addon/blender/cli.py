"""Command line bake, shared by `blender -b scene.blend -c hr_bake ...` and
`python -m hr_addon bake scene.blend ...`.

Exit codes: 0 success; 1 the scene cannot be baked (no meshes, nothing emits, invalid geometry, ...);
2 bad command line (unknown option, bad frame range, missing or unreadable .blend file, bad --save);
130 cancelled (Ctrl-C or SIGTERM; the previous bake is kept, no temporary folder is left).
Errors are one line on stderr: "hr_bake: error: <reason>".
"""

import argparse
import os
import re
import sys

from .settings import (
    VERTEX_SPACING,
    choices,
    density_problem,
    resolution_problem,
    spacing_problem,
    thresholds_problem,
)

PROG = "hr_bake"

EXIT_CODES = """exit codes:
  0    success
  1    the scene cannot be baked (no meshes, nothing emits light, NaN coordinates,
       invalid light shape, cannot write the cache)
  2    bad command line (unknown option, bad frame range, missing or unreadable .blend,
       bad --save path)
  130  cancelled by Ctrl-C or SIGTERM: the previous bake is kept, no temporary folder is left

Errors are one line on stderr: "hr_bake: error: <reason>". Warnings are listed once after the
summary line (repeats counted). Options default to the scene's settings (Render Properties >
HR Radiosity)."""


class UsageError(Exception):
    pass


class _Parser(argparse.ArgumentParser):
    def error(self, message):
        raise UsageError(message)


def make_parser(prog=PROG, blend_required=False):
    p = _Parser(
        prog=prog,
        description="Bake dynamic hierarchical radiosity into the HR_Radiance "
        "attribute cache (or baked textures) of a .blend file.",
        epilog=EXIT_CODES,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )

    def setting(flag, text):  # one of a Scene setting's choices (settings.py), case-insensitive
        p.add_argument(flag, type=str.lower, choices=choices(flag[2:].replace("-", "_")), help=text)

    p.add_argument(
        "blend",
        nargs=None if blend_required else "?",
        help="the .blend file (default: the file Blender opened)",
    )
    p.add_argument(
        "--frames", metavar="A-B", help="frame range, e.g. 1-250, or one frame (default: the scene's)"
    )
    setting(
        "--method",
        "how light-shape changes are applied: auto (chosen per element by an error bound; "
        "recommended), ar (adaptive refinement), fe (fractional emission, fastest), naive (rebuild, "
        "slow reference)",
    )
    setting(
        "--output",
        "vertex colours (HR_Radiance) or baked textures (default: the scene's)",
    )
    setting(
        "--radiance-mode",
        "values: outgoing radiance, irradiance / pi for lightmaps the material colour "
        "multiplies, or indirect: that without the Blender lights' and the World's direct light, "
        "for EEVEE (needs the final gather; default: the scene's)",
    )
    p.add_argument(
        "--resolution",
        type=int,
        metavar="N",
        help="texture size in texels, 8 to 16384: the largest lightmap (texture output; every object's "
        "with --texel-density 0; default: the scene's Texture Size, 1024 unless set)",
    )
    p.add_argument(
        "--texel-density",
        type=float,
        metavar="D",
        help="lightmap texels per metre of surface: each object's lightmap sized by its area, up to "
        "--resolution (0: every object --resolution; default: the scene's Texel Density, 50)",
    )
    p.add_argument(
        "--vertex-spacing",
        type=float,
        metavar="S",
        help="vertex output with the final gather: objects with edges longer than S metres show their "
        "light at the corners of their mesh subdivided until none is (0: the mesh's own corners; "
        f"default: the scene's Vertex Spacing, {VERTEX_SPACING:g} unless set)",
    )
    setting(
        "--texture-format",
        "texture files: exr (32-bit float, linear) or png (16-bit, sRGB)",
    )
    setting(
        "--quality",
        "refinement preset; custom uses --feps and --aeps",
    )
    p.add_argument("--feps", type=float, help="form factor threshold, 0 < F <= 1 (implies --quality custom)")
    p.add_argument(
        "--aeps",
        type=float,
        help="smallest element area as a fraction of the scene's area, 0 < A < 1 (implies --quality custom)",
    )
    p.add_argument(
        "--no-contacts",
        action="store_true",
        help="do not look for surfaces covered by objects standing on them (Scene setting Contacts)",
    )
    p.add_argument(
        "--no-final-gather",
        action="store_true",
        help="show the hierarchy's elements instead of gathering each output point's own light "
        "(Scene setting Final Gather; the classic hierarchical radiosity output)",
    )
    setting(
        "--domain",
        "vertex output per face corner (creases stay sharp) or per vertex",
    )
    p.add_argument(
        "--threads",
        type=int,
        metavar="N",
        help="threads for the bake (default: the Scene setting Threads; 0: every core). "
        "The result does not depend on it",
    )
    p.add_argument("--scene", help="scene name (default: the active scene)")
    p.add_argument("--view-layer", help="view layer name (default: the window's, else the first)")
    p.add_argument(
        "--save",
        metavar="PATH",
        help="save a copy of the .blend (with the bake settings) to PATH; "
        "the bake itself is in the input file's cache folder",
    )
    p.add_argument(
        "--cache-dir",
        metavar="DIR",
        help="write the bake into DIR (absolute; default: the scene's cache folder next to the .blend)",
    )
    p.add_argument(
        "--rebuild",
        action="store_true",
        help="build the scene precompute (hierarchy, links, final gather) even if the cache folder "
        "holds a valid one",
    )
    p.add_argument(
        "--status-file",
        metavar="PATH",
        help="keep a JSON progress status in PATH (the interactive background bake reads it)",
    )
    return p


def parse_frames(text):
    m = re.fullmatch(r"\s*(-?\d+)\s*(?:(?:-|\.\.|:)\s*(-?\d+)\s*)?", text or "")
    if not m:
        raise UsageError(f"bad frame range '{text}' (expected A-B, e.g. 1-250)")
    a = int(m.group(1))
    b = int(m.group(2)) if m.group(2) is not None else a
    if b < a:
        raise UsageError(f"bad frame range '{text}': the end frame is before the start frame")
    return a, b


def check_args(args):
    """The checks that need no bpy (before its slow import and before the build): the frame range,
    the .blend file, the texture size and the --save path. Returns the frames (or None); raises
    UsageError."""
    frames = parse_frames(args.frames) if args.frames is not None else None
    if args.blend is not None and not os.path.isfile(args.blend):
        raise UsageError(f"file not found: {args.blend}")
    if args.threads is not None and args.threads < 0:
        raise UsageError(f"bad --threads {args.threads} (0: every core, or a count)")
    if args.resolution is not None and resolution_problem(args.resolution):
        raise UsageError(resolution_problem(args.resolution))
    if args.texel_density is not None and density_problem(args.texel_density):
        raise UsageError(density_problem(args.texel_density))
    if args.vertex_spacing is not None and spacing_problem(args.vertex_spacing):
        raise UsageError(spacing_problem(args.vertex_spacing))
    if args.save:
        path = os.path.abspath(args.save)
        folder = os.path.dirname(path)
        if not path.lower().endswith(".blend"):
            raise UsageError(f"--save {args.save}: the copy needs a .blend file name")
        if not os.path.isdir(folder):
            raise UsageError(f"--save {args.save}: the folder {folder} does not exist")
        if os.path.isdir(path):
            raise UsageError(f"--save {args.save}: {path} is a folder")
        if not os.access(folder, os.W_OK) or (os.path.exists(path) and not os.access(path, os.W_OK)):
            raise UsageError(f"--save {args.save}: cannot write {path} (permission denied)")
    return frames


def _err(msg):
    print(f"{PROG}: error: {msg}", file=sys.stderr, flush=True)


def cancelled_message():
    return f"{PROG}: cancelled; the previous bake is kept"


def run(argv, prog=PROG, blend_required=False, interrupts=None):
    """Parse argv and bake; returns the exit code (never raises for bad input).

    interrupts: an interrupt.Interrupts already installed (python -m hr_addon installs it before
    importing bpy, so a Ctrl-C then is not lost); otherwise SIGINT and SIGTERM are handled from
    here on. Either way the previous handlers are back when run() returns."""
    from .interrupt import INTERRUPTS

    intr = (interrupts or INTERRUPTS).install()
    try:
        return _run(argv, prog, blend_required, intr)
    finally:
        intr.restore()


def _run(argv, prog, blend_required, intr):
    try:
        args = make_parser(prog, blend_required).parse_args(list(argv))
        frames = check_args(args)
    except UsageError as exc:
        _err(str(exc))
        return 2

    import bpy
    from ..core.geometry import InputError
    from ..core.progress import Cancelled
    from .bake import Warnings, run_bake
    from .jobstatus import StatusWriter

    status = None
    if args.status_file:
        try:
            status = StatusWriter(args.status_file, cache_dir=args.cache_dir or "")
        except OSError as exc:
            _err(f"cannot write the status file {args.status_file}: {exc}")
            return 1

    def fail(code, msg):
        _err(msg)
        if status is not None:
            status.write(state="failed", error=msg)
        return code

    def cancelled():
        print(cancelled_message(), file=sys.stderr, flush=True)
        if status is not None:
            status.write(state="cancelled")
        return 130

    if intr.requested:
        return cancelled()
    if args.blend is not None:
        try:
            bpy.ops.wm.open_mainfile(filepath=os.path.abspath(args.blend), load_ui=False)
        except RuntimeError as exc:
            return fail(
                2,
                f"cannot open {args.blend}: {str(exc).strip().splitlines()[-1] if str(exc).strip() else exc}",
            )
    elif not bpy.data.filepath:
        return fail(2, "no .blend file loaded (pass one: blender -b scene.blend -c hr_bake ...)")
    if intr.requested:
        return cancelled()
    scene = bpy.context.scene
    if args.scene:
        scene = bpy.data.scenes.get(args.scene)
        if scene is None:
            return fail(2, f"no scene named '{args.scene}'")
    view_layer = scene.view_layers[0] if scene != bpy.context.scene else None
    if args.view_layer:
        view_layer = scene.view_layers.get(args.view_layer)
        if view_layer is None:
            return fail(2, f"no view layer named '{args.view_layer}' in scene '{scene.name}'")
    if args.cache_dir is not None and not os.path.isabs(args.cache_dir):
        return fail(2, f"--cache-dir must be an absolute path, got '{args.cache_dir}'")
    quality = args.quality
    if args.feps is not None or args.aeps is not None:
        quality = "custom"
    feps = args.feps if args.feps is not None else scene.hr.feps
    aeps = args.aeps if args.aeps is not None else scene.hr.aeps
    if quality == "custom" and thresholds_problem(feps, aeps):
        return fail(2, thresholds_problem(feps, aeps))
    collected = Warnings()
    try:
        res = run_bake(
            scene,
            view_layer=view_layer,
            frames=frames,
            method=args.method,
            quality=quality,
            domain=args.domain,
            feps=feps,
            aeps=aeps,
            output=args.output,
            resolution=args.resolution,
            texel_density=args.texel_density,
            vertex_spacing=args.vertex_spacing,
            texture_format=args.texture_format,
            radiance_mode=args.radiance_mode,
            contacts=False if args.no_contacts else None,
            final_gather=False if args.no_final_gather else None,
            threads=args.threads,
            cache_dir=args.cache_dir,
            rebuild=args.rebuild,
            status=status.progress if status is not None else None,
            interrupts=intr,
            warnings=collected,
        )
    except (Cancelled, KeyboardInterrupt, SystemExit):
        # Ctrl-C or SIGTERM (the interactive bake's Cancel): the partial bake was removed.
        return cancelled()
    except InputError as exc:
        return fail(1, str(exc).replace("\n", " "))
    except OSError as exc:
        return fail(1, f"cannot write the cache: {exc}")
    except Exception as exc:  # a bug: still one line (HR_DEBUG=1 prints the traceback)
        if os.environ.get("HR_DEBUG"):
            import traceback

            traceback.print_exc()
        return fail(
            1, f"internal error: {type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}"
        )
    late = intr.requested  # came after the commit: the new bake is complete and kept
    if args.save and not late:
        keep_settings(scene.hr, args, quality, feps, aeps)
        path = os.path.abspath(args.save)
        try:
            bake_abs = os.path.abspath(bpy.path.abspath(scene.hr.bake_dir))
            rel = os.path.relpath(bake_abs, os.path.dirname(path))
            scene.hr.bake_dir = "//" + rel.replace(os.sep, "/").rstrip("/") + "/"
        except ValueError:
            pass
        try:
            bpy.ops.wm.save_as_mainfile(filepath=path, check_existing=False)
        except RuntimeError as exc:
            _err(f"cannot save {args.save}: {exc}")
            return 1
        print(f"{PROG}: saved {path}", flush=True)
    lines = res.warning_lines()
    if lines:
        print(f"{PROG}: {len(lines)} warning(s) (listed above)", flush=True)
    if status is not None:
        status.write(
            state="done",
            fraction=1.0,
            eta=None,
            summary=res.summary(),
            rays=res.rays,
            cache_dir=res.cache_dir,
            output=(args.output or scene.hr.output).upper(),
            message=f"Baked frames {res.frames[0]}-{res.frames[1]}",
            warnings=lines,
        )
    if late:
        print(
            f"{PROG}: the cancel came after the bake was complete; the new bake is kept"
            + (" (the copy was not saved)" if args.save else ""),
            file=sys.stderr,
            flush=True,
        )
    return 0


def keep_settings(hr, args, quality, feps, aeps):
    """Write the options the bake used into Scene.hr, so that the saved copy's panel and its next
    bake show them (a texture bake left Output on Vertex)."""
    for key in ("method", "output", "domain", "radiance_mode", "texture_format"):
        if getattr(args, key):
            setattr(hr, key, getattr(args, key).upper())
    if quality:
        hr.quality = quality.upper()
    if hr.quality == "CUSTOM":
        hr.feps, hr.aeps = feps, aeps
    if args.resolution:
        hr.texture_resolution = args.resolution
    if args.texel_density is not None:
        hr.texel_density = args.texel_density
    if args.vertex_spacing is not None:
        hr.vertex_spacing = args.vertex_spacing
    if args.no_contacts:
        hr.contacts = False
    if args.no_final_gather:
        hr.final_gather = False


def cli_command(argv):
    """Callback of `blender -c hr_bake`."""
    return run(argv)
