"""Command line bake, shared by `blender -b scene.blend -c hr_bake ...` and
`python -m hr_addon bake scene.blend ...`.

Exit codes: 0 success; 1 the scene cannot be baked (no meshes, invalid geometry, ...);
2 bad command line (unknown option, bad frame range, missing or unreadable .blend file).
Errors are one line on stderr: "hr_bake: error: <reason>".
"""
import argparse
import os
import re
import sys

PROG = "hr_bake"


class UsageError(Exception):
    pass


class _Parser(argparse.ArgumentParser):
    def error(self, message):
        raise UsageError(message)


def make_parser(prog=PROG, blend_required=False):
    p = _Parser(prog=prog, description="Bake dynamic hierarchical radiosity into the HR_Radiance "
                                       "attribute cache (or baked textures) of a .blend file.")
    p.add_argument("blend", nargs=None if blend_required else "?",
                   help="the .blend file (default: the file Blender opened)")
    p.add_argument("--frames", metavar="A-B", help="frame range (default: the scene's)")
    p.add_argument("--method", type=str.lower, choices=["ar", "fe", "naive", "auto"])
    p.add_argument("--output", type=str.lower, choices=["vertex", "texture"],
                   help="vertex colours (HR_Radiance) or baked textures (default: the scene's)")
    p.add_argument("--resolution", type=int, metavar="N", help="texture size in texels (texture output)")
    p.add_argument("--texture-format", type=str.lower, choices=["exr", "png"], help="texture file format")
    p.add_argument("--quality", type=str.lower, choices=["draft", "medium", "high", "custom"])
    p.add_argument("--feps", type=float, help="form factor threshold (implies --quality custom)")
    p.add_argument("--aeps", type=float, help="area threshold (implies --quality custom)")
    p.add_argument("--domain", type=str.lower, choices=["corner", "point"])
    p.add_argument("--scene", help="scene name (default: the active scene)")
    p.add_argument("--save", metavar="PATH", help="save the .blend (with the bake settings) to PATH")
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


def _err(msg):
    print(f"{PROG}: error: {msg}", file=sys.stderr, flush=True)


def run(argv, prog=PROG, blend_required=False):
    """Parse argv and bake; returns the exit code (never raises for bad input)."""
    try:
        args = make_parser(prog, blend_required).parse_args(list(argv))
        frames = parse_frames(args.frames) if args.frames is not None else None
        if args.blend is not None and not os.path.isfile(args.blend):
            raise UsageError(f"file not found: {args.blend}")
        if args.resolution is not None and not 8 <= args.resolution <= 16384:
            raise UsageError(f"bad texture resolution {args.resolution} (8 to 16384)")
    except UsageError as exc:
        _err(str(exc))
        return 2

    import bpy
    from ..core.geometry import InputError
    from .bake import run_bake

    if args.blend is not None:
        try:
            bpy.ops.wm.open_mainfile(filepath=os.path.abspath(args.blend), load_ui=False)
        except RuntimeError as exc:
            _err(f"cannot open {args.blend}: {str(exc).strip().splitlines()[-1] if str(exc).strip() else exc}")
            return 2
    elif not bpy.data.filepath:
        _err("no .blend file loaded (pass one: blender -b scene.blend -c hr_bake ...)")
        return 2
    scene = bpy.context.scene
    if args.scene:
        scene = bpy.data.scenes.get(args.scene)
        if scene is None:
            _err(f"no scene named '{args.scene}'")
            return 2
    quality = args.quality
    if args.feps is not None or args.aeps is not None:
        quality = "custom"
    feps = args.feps if args.feps is not None else scene.hr.feps
    aeps = args.aeps if args.aeps is not None else scene.hr.aeps
    if quality == "custom" and not (0 < feps <= 1 and 0 < aeps < 1):
        _err(f"bad thresholds feps={feps} aeps={aeps} (need 0 < feps <= 1, 0 < aeps < 1)")
        return 2
    try:
        res = run_bake(scene, view_layer=scene.view_layers[0] if scene != bpy.context.scene else None,
                       frames=frames, method=args.method, quality=quality, domain=args.domain,
                       feps=feps, aeps=aeps, output=args.output, resolution=args.resolution,
                       texture_format=args.texture_format)
    except InputError as exc:
        _err(str(exc).replace("\n", " "))
        return 1
    except OSError as exc:
        _err(f"cannot write the cache: {exc}")
        return 1
    except Exception as exc:  # a bug: still one line (HR_DEBUG=1 prints the traceback)
        if os.environ.get("HR_DEBUG"):
            import traceback
            traceback.print_exc()
        _err(f"internal error: {type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}")
        return 1
    if args.save:
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
    if res.warnings:
        print(f"{PROG}: {len(res.warnings)} warning(s)", flush=True)
    return 0


def cli_command(argv):
    """Callback of `blender -c hr_bake`."""
    return run(argv)
