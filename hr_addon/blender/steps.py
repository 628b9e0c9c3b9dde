"""Work the UI thread spreads over timer ticks: generators that yield after each bounded step and
return their result (StopIteration.value). No bpy."""

import time


def finish(steps):
    """Run `steps` to its end in one call (scripts, background mode): its return value."""
    while True:
        try:
            next(steps)
        except StopIteration as done:
            return done.value


def advance(steps, seconds):
    """Run `steps` for about `seconds`, one step at least: (steps taken, finished, its return value
    once finished else None). A step's ReferenceError (bpy data removed meanwhile) passes through."""
    end = time.perf_counter() + seconds
    taken = 0
    try:
        while True:
            next(steps)
            taken += 1
            if time.perf_counter() >= end:
                return taken, False, None
    except StopIteration as done:
        return taken, True, done.value
