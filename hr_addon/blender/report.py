"""What a bake reports: its progress steps, its result (summary line) and its warnings, each
shown once with repeats counted; and which ray tracer it used."""

import re
from collections import OrderedDict
from dataclasses import dataclass, field

from ..io.cache import frame_ranges


@dataclass
class BakeProgress:
    stage: str  # "build", "frame"
    frame: int = 0
    done: int = 0  # frames finished
    total: int = 0
    message: str = ""
    reused: bool = False
    warnings: list = field(default_factory=list)
    fraction: float = 0.0  # of the whole bake (estimate: the build counts as BUILD_SHARE)
    eta: float = float("nan")  # seconds left of the current stage (nan: unknown yet)


BUILD_SHARE = 0.5  # share of the progress bar given to the hierarchy build


def ray_backend_name(system):
    """ "embree", "numpy", ... of the ray backend a RadiositySystem was built with."""
    name = getattr(getattr(system, "backend", None), "name", "")
    if not name:  # BuildReport.backend holds the class name, e.g. "EmbreeBackend"
        cls = str(getattr(getattr(system, "build", None), "backend", "") or "unknown")
        name = cls[: -len("Backend")].lower() if cls.endswith("Backend") else cls.lower()
    return name


def ray_backend_note(name):
    """'' for Embree, else why the bake traces rays with `name` (shown in the summary line)."""
    if name == "embree":
        return ""
    try:
        import embreex.mesh_construction  # noqa: F401
        import embreex.rtcore_scene  # noqa: F401
    except ImportError as exc:
        return f"embreex not available on this platform/Python ({exc}); numpy tracer, slower"
    return "numpy tracer"


class Warnings:
    """The bake's warnings, each shown once: repeats (the same shape on every frame, numbers
    aside) are counted, with the frames they came from."""

    def __init__(self):
        self.items = OrderedDict()  # key -> [first text, count, frames]

    @staticmethod
    def key(text):
        return re.sub(r"\d+(?:\.\d+)?", "#", text)

    def add(self, text, frame=None):
        """Count one occurrence; True if it is the first of its kind."""
        k = self.key(text)
        item = self.items.get(k)
        if item is None:
            self.items[k] = [text, 1, [] if frame is None else [frame]]
            return True
        item[1] += 1
        if frame is not None and frame not in item[2]:
            item[2].append(frame)
        return False

    def texts(self):
        return [v[0] for v in self.items.values()]

    def lines(self):
        out = []
        for text, count, frames in self.items.values():
            if count > 1:
                where = f" on frames {frame_ranges(frames)}" if frames else ""
                text = f"{text} [{count} times{where}]"
            out.append(text)
        return out

    def __len__(self):
        return len(self.items)


@dataclass
class BakeResult:
    cache_dir: str = ""
    frames: tuple = (0, 0)
    solved: int = 0  # frames that needed a new solution
    reused: int = 0  # frames identical to the previous one
    kept: int = 0  # frames of the previous bake kept outside the range
    rebaked: list = field(default_factory=list)  # previous bake's frames baked again: damaged or relit
    warnings: list = field(default_factory=list)  # each warning once (first text); see warning_lines
    notes: list = field(default_factory=list)  # log lines that ask nothing of the user (progress messages)
    log: object = None  # the Warnings collector (counts and frames of repeats)
    build_seconds: float = 0.0
    gather_seconds: float = 0.0  # the final gather's precompute (0: off or loaded)
    precompute: list = field(default_factory=list)  # what the build stage did, and why
    precompute_loaded: bool = False  # the scene precompute came from the cache folder
    load_seconds: float = 0.0  # of build_seconds, the precompute's key and load (when loaded)
    seconds: float = 0.0
    build_report: object = None
    rays: str = ""  # ray backend of the build ("embree", "numpy", ...)
    rays_note: str = ""  # why not embree, if not

    def warning_lines(self):
        """Every warning once, repeats counted ('... [8 times on frames 6-13]')."""
        return self.log.lines() if self.log is not None else list(self.warnings)

    @property
    def rays_text(self):
        return f"rays: {self.rays}" + (f" ({self.rays_note})" if self.rays_note else "")

    def summary(self):
        again = f", {len(self.rebaked)} re-baked (damaged or relit)" if self.rebaked else ""
        return (
            f"baked frames {self.frames[0]}-{self.frames[1]} into {self.cache_dir}: "
            f"{self.solved} solved, {self.reused} unchanged, {self.kept} kept from the previous bake{again} "
            + (
                f"({self.precompute[0]}: {self.build_seconds:.1f} s, "
                if self.precompute_loaded
                else "("
                + (f"{self.precompute[0]}; " if self.precompute else "")
                + f"hierarchy {self.build_seconds:.1f} s, "
                + (
                    f"final gather {self.gather_seconds:.1f} s, "
                    if self.gather_seconds
                    else "final gather off, "
                )
            )
            + f"total {self.seconds:.1f} s, {self.rays_text})"
        )
