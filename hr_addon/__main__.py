"""`python -m hr_addon bake scene.blend [options]` with Blender as a Python module (bpy).

The same options as `blender -b scene.blend -c hr_bake [options]`; see hr_addon/blender/cli.py.
"""

import sys


def usage():
    """The usage line, from the bake command's own parser (never out of date)."""
    from .blender.cli import make_parser

    u = make_parser("python -m hr_addon bake", blend_required=True).format_usage().strip()
    return (
        f"{u}\n\nBake dynamic hierarchical radiosity into a .blend file's cache. "
        "Options and exit codes: python -m hr_addon bake --help"
    )


def main(argv=None):
    argv = list(sys.argv[1:] if argv is None else argv)
    # Ctrl-C / SIGTERM from here on are recorded, not raised: a KeyboardInterrupt inside bpy's
    # start-up (add-on registration) prints tracebacks and can crash it. The bake checks them.
    from .blender.interrupt import INTERRUPTS

    if argv and argv[0] == "bake":
        INTERRUPTS.install()
    try:
        return _main(argv, INTERRUPTS)
    finally:
        INTERRUPTS.restore()


def _cancelled(INTERRUPTS):
    """A Ctrl-C or SIGTERM came during the start-up: say so (exit code 130)."""
    from .blender import cli

    if INTERRUPTS.requested:
        print(cli.cancelled_message(), file=sys.stderr, flush=True)
    return INTERRUPTS.requested


def _main(argv, INTERRUPTS):
    if not argv or argv[0] in ("-h", "--help"):
        print(usage())
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
        cli.check_args(cli.make_parser("python -m hr_addon bake", blend_required=True).parse_args(argv[1:]))
    except cli.UsageError as exc:
        print(f"{cli.PROG}: error: {exc}", file=sys.stderr, flush=True)
        return 2
    if _cancelled(INTERRUPTS):
        return 130
    try:
        import bpy  # noqa: F401
    except ImportError:
        print(f"{cli.PROG}: error: the bpy module is not installed (pip install bpy)", file=sys.stderr)
        return 1
    if _cancelled(INTERRUPTS):
        return 130
    from . import register

    register()
    return cli.run(argv[1:], prog="python -m hr_addon bake", blend_required=True, interrupts=INTERRUPTS)


if __name__ == "__main__":
    sys.exit(main())
