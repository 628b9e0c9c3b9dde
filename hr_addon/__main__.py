"""`python -m hr_addon bake scene.blend [options]` with Blender as a Python module (bpy).

The same options as `blender -b scene.blend -c hr_bake [options]`; see hr_addon/blender/cli.py.
"""
import os
import sys

USAGE = "usage: python -m hr_addon bake BLEND [--frames A-B] [--method ar|fe|naive|auto] " \
        "[--output vertex] [--quality draft|medium|high] [--save PATH]"


def main(argv=None):
    argv = list(sys.argv[1:] if argv is None else argv)
    if not argv or argv[0] in ("-h", "--help"):
        print(USAGE)
        return 0 if argv else 2
    if argv[0] != "bake":
        print(f"python -m hr_addon: error: unknown command '{argv[0]}' (expected 'bake')", file=sys.stderr)
        return 2
    if any(a in ("-h", "--help") for a in argv[1:]):
        from .blender.cli import make_parser
        make_parser("python -m hr_addon bake", blend_required=True).print_help()
        return 0
    # Validate the arguments before the (slow) bpy import.
    from .blender import cli
    try:
        args = cli.make_parser("python -m hr_addon bake", blend_required=True).parse_args(argv[1:])
        if args.frames is not None:
            cli.parse_frames(args.frames)
        if not os.path.isfile(args.blend):
            raise cli.UsageError(f"file not found: {args.blend}")
    except cli.UsageError as exc:
        print(f"{cli.PROG}: error: {exc}", file=sys.stderr, flush=True)
        return 2
    try:
        import bpy  # noqa: F401
    except ImportError:
        print(f"{cli.PROG}: error: the bpy module is not installed (pip install bpy)", file=sys.stderr)
        return 1
    from . import register
    register()
    return cli.run(argv[1:], prog="python -m hr_addon bake", blend_required=True)


if __name__ == "__main__":
    sys.exit(main())
