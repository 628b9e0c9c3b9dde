"""A deterministic batch map on threads (issue 23, docs/threads.md).

Work is cut into batches whose bounds never depend on the thread count; every batch computes its
own result and the results come back in batch order, so 1 and N threads give bitwise equal
values. Threads pay where the kernels release the GIL (embreex's ray queries, numpy's large array
operations; measured in docs/threads.md).

- threads=1 runs the batches inline: no thread (the single-core path).
- threads=N: the calling thread and N - 1 worker threads started for the map each take the next
  batch until none is left (no waiting caller woken at every batch: session 20, docs/threads.md).
- A batch map started inside a batch of another runs inline: no nested threads.
- Cancellation: `progress(done, total)` is called from the calling thread, between its own
  batches or while it waits for the last ones, once per finished batch, in order (done = 1, 2,
  ...). Whatever it raises (core.progress.Cancelled, or the signal handler's Cancelled /
  KeyboardInterrupt arriving in the calling thread, in its batch or while it waits) stops the
  map: no batch starts after it, the running ones are waited for and it propagates: no worker
  thread is left behind. A batch that raises does the same with its exception.
"""

import heapq
import os
import sys
import threading
import time
from contextlib import contextmanager
from itertools import count

_local = threading.local()
_pools = count()  # a name per pool, so that its threads can be found (batch_map's finally)
_counts_lock = threading.Lock()
_profile = None  # profiled(): the CPU seconds of each batch of every outermost inline batch map


def available_cores():
    """Cores this process may run on (its CPU affinity: `taskset` counts)."""
    try:
        return max(len(os.sched_getaffinity(0)), 1)
    except AttributeError:  # not on Linux
        return max(os.cpu_count() or 1, 1)


def memory_headroom():
    """Bytes this process may still take, as far as the system tells (None: unknown): the memory
    available (Linux: MemAvailable; Windows: the available physical memory; elsewhere the total),
    or the room left under an address-space limit (ulimit -v) when that is less."""
    room = []
    try:
        with open("/proc/meminfo") as fh:
            room += [int(line.split()[1]) * 1024 for line in fh if line.startswith("MemAvailable:")]
    except OSError:
        if os.name == "nt":
            import ctypes

            class Status(ctypes.Structure):
                _fields_ = [("length", ctypes.c_uint32), ("load", ctypes.c_uint32)] + [
                    (k, ctypes.c_uint64) for k in ("total", "avail", "tpage", "apage", "tvirt", "avirt", "x")
                ]

            st = Status(length=ctypes.sizeof(Status))
            if ctypes.windll.kernel32.GlobalMemoryStatusEx(ctypes.byref(st)):
                room.append(int(st.avail))
        else:
            try:
                room.append(os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE"))
            except (ValueError, OSError, AttributeError):
                pass
    try:
        import resource

        limit = resource.getrlimit(resource.RLIMIT_AS)[0]
        if limit != resource.RLIM_INFINITY:
            with open("/proc/self/status") as fh:
                used = [int(line.split()[1]) * 1024 for line in fh if line.startswith("VmSize:")]
            room.append(limit - (used[0] if used else 0))
    except (ImportError, OSError, ValueError):
        pass
    return min(room) if room else None


_trim = []  # release_free_memory(): glibc's malloc_trim, once looked up (None: not there)


def release_free_memory():
    """Give the C heap's free pages back to the system (glibc's malloc_trim; elsewhere nothing).
    numpy's arrays below glibc's mmap threshold (which grows to 32 MB as large arrays are freed)
    live in the heap, whose freed pages stay resident: 0.3-0.45 GB of the 100k vertex bake's RSS
    between its stages (docs/scale.md, session 32). Called between stages that free much, it keeps
    that out of the next stage's peak; a few ms, no values change."""
    if not _trim:
        fn = None
        if sys.platform.startswith("linux"):
            try:
                import ctypes

                fn = ctypes.CDLL(None).malloc_trim
                fn.argtypes, fn.restype = [ctypes.c_size_t], ctypes.c_int
            except (OSError, AttributeError):  # (not glibc: musl has none)
                fn = None
        _trim.append(fn)
    if _trim[0] is not None:
        _trim[0](0)


def trimming(fn, every):
    """fn, the heap's freed pages given back (release_free_memory) after every `every`-th call (on
    any thread; every 0: fn itself): a long map's batches each free their temporaries, and the
    arrays they keep land in the holes, so freed pages pile up resident within one stage (~0.4 GB
    at the 100k vertex bake's gather precompute; docs/scale.md, session 36). No values change; the
    next batches fault the given-back pages in again (system CPU)."""
    if not every:
        return fn
    calls = count(1)

    def run(*args):
        out = fn(*args)
        if next(calls) % every == 0:
            release_free_memory()
        return out

    return run


def resolve_threads(threads):
    """threads: None or 0 -> every available core; n < 0 -> all but |n| (Live keeps one for the
    UI); otherwise n. At least 1."""
    cores = available_cores()
    if threads is None or threads == 0:
        return cores
    threads = int(threads)
    return max(cores + threads if threads < 0 else threads, 1)


def add_counts(stats, **add):
    """stats[key] += value for each keyword, under a lock: counters that batch_map's workers update
    (a dict's += is a read and a write: two workers could lose one of them)."""
    with _counts_lock:
        for key, v in add.items():
            stats[key] += v


def ranges(n, step):
    """[(a, b), ...] covering 0..n in steps of `step` (fixed by the caller, never by the thread
    count: the bounds of the batches, and so the results, are the same for any thread count)."""
    step = max(int(step), 1)
    return [(a, min(a + step, n)) for a in range(0, n, step)]


def spans(n, step, count=16, grow=4):
    """ranges(n, s) with s between `step` and grow x step: the largest that still leaves `count`
    batches (16 cores' worth: docs/threads.md's model). A build batch's numpy calls hold the GIL
    for their set-up, 10-27% of its CPU at 2^13 items (docs/threads.md, session 33): a large map
    takes fewer, larger calls, a small one keeps `step`. s depends on n only, never on the thread
    count."""
    return ranges(n, min(max(-(-n // count), step), grow * step))


def in_worker():
    """True inside a batch of a threaded batch map (in a worker or in the calling thread)."""
    return getattr(_local, "worker", False)


def batch_map(fn, batches, threads=1, progress=None, poll=0.1):
    """[fn(*batch) for batch in batches], computed on up to `threads` threads, in batch order.

    batches: argument tuples (e.g. ranges()). progress(done, total): see the module doc; it may
    raise to cancel. A thread takes a batch only when it starts it, so a cancel waits for the
    running batches only."""
    batches = list(batches)
    total = len(batches)
    threads = min(resolve_threads(threads), total)
    if threads <= 1 or in_worker():
        # profiled(): only the outermost map's batches count (a map inside a batch is part of it)
        outer = not getattr(_local, "mapping", False)
        seconds, out = [], []
        _local.mapping = True
        try:
            for k, b in enumerate(batches):
                t0 = time.thread_time()
                out.append(fn(*b))
                seconds.append(time.thread_time() - t0)
                if progress is not None:
                    progress(k + 1, total)
        finally:
            _local.mapping = not outer
        if _profile is not None and outer and not in_worker():
            _profile.append(seconds)
        return out
    return _Map(fn, batches, progress).run(threads, poll)


class _Map:
    """One threaded batch map: the calling thread and threads - 1 workers started for it each take
    the next batch (a shared index) until none is left, the error or the cancel stops them. The
    calling thread works too (a pool of `threads` workers left it waiting, woken at every batch:
    docs/threads.md, session 20), and between its batches it reports the finished ones in order."""

    def __init__(self, fn, batches, progress):
        self.fn, self.batches, self.progress = fn, batches, progress
        self.out = [None] * len(batches)
        self.finished = [False] * len(batches)
        self.next = 0
        self.stop = False
        self.error = None
        self.cond = threading.Condition()

    def take(self):
        """The next batch's index, None when none is left or the map stops."""
        with self.cond:
            if self.stop or self.next >= len(self.batches):
                return None
            self.next += 1
            return self.next - 1

    def run_batch(self, k):
        _local.worker = True  # a map inside a batch runs inline (no nested pools)
        try:
            self.out[k] = self.fn(*self.batches[k])
        finally:
            _local.worker = False
        with self.cond:
            self.finished[k] = True
            self.cond.notify_all()

    def work(self):
        try:
            while (k := self.take()) is not None:
                self.run_batch(k)
        except BaseException as exc:  # handed to the calling thread, which raises it
            with self.cond:
                self.error = self.error or exc
                self.stop = True
                self.cond.notify_all()

    def run(self, threads, poll):
        total = len(self.batches)
        name = f"hr-batch-{next(_pools)}"
        workers = [threading.Thread(target=self.work, name=f"{name}_{i}") for i in range(threads - 1)]
        done = 0
        try:
            for t in workers:
                t.start()
            while done < total:
                k = self.take()
                if k is not None:
                    self.run_batch(k)
                else:  # a timeout keeps the calling thread responsive to signals while it waits
                    with self.cond:
                        self.cond.wait_for(lambda: self.error or self.finished[done], timeout=poll)
                if self.error is not None:
                    raise self.error
                while done < total and self.finished[done]:
                    done += 1
                    if self.progress is not None:
                        self.progress(done, total)
        finally:
            # normal end, cancel or error alike: nothing new starts, running batches are joined
            with self.cond:
                self.stop = True
            for t in workers:
                if t.ident is not None:
                    t.join()
        return self.out


@contextmanager
def profiled():
    """Within it, every outermost batch map run inline (threads=1) appends the CPU seconds of its
    batches to the yielded list: benchmarks/bench_threads.py's measure of what runs on threads and
    what stays serial (Amdahl's law, docs/threads.md). Not thread-safe; for one bake at a time."""
    global _profile
    _profile = []
    try:
        yield _profile
    finally:
        _profile = None


def makespan(seconds, threads):
    """Wall seconds of batches taking `seconds` each (in order) on `threads` workers that each take
    the next batch when free, as batch_map's pool does: the model of a map on more cores (it
    assumes a batch takes as long on any core, i.e. no memory bandwidth or cache limit)."""
    free = [0.0] * max(int(threads), 1)
    for s in seconds:
        heapq.heapreplace(free, free[0] + s)
    return max(free)
