"""glibc's heap and this process's RSS for the memory benchmarks (gathermem_marks.py,
blender_rss.py, blender_before_build.py): one copy of the mallinfo2 binding."""

import ctypes


class _Mallinfo2(ctypes.Structure):
    _fields_ = [
        (n, ctypes.c_size_t)
        for n in "arena ordblks smblks hblks hblkhd usmblks fsmblks uordblks fordblks keepcost".split()
    ]


try:
    _libc = ctypes.CDLL("libc.so.6")
    _libc.mallinfo2.restype = _Mallinfo2
except (OSError, AttributeError):  # not glibc, or glibc before 2.33
    _libc = None


def mallinfo():
    """glibc's mallinfo2 (uordblks in use, fordblks free, hblkhd mmapped), or None without it."""
    return None if _libc is None else _libc.mallinfo2()


def rss_gb():
    with open("/proc/self/status") as f:
        return next(int(x.split()[1]) for x in f if x.startswith("VmRSS")) / 1e6
