"""The control loop ahead of the rest of the machine: real-time priority for its thread,
and the garbage collector kept off its path.

A robot computer runs SLAM, navigation and cameras beside the base driver. At normal
priority the loop thread waits its turn among them, and a loop late by the drives'
heartbeat-consumer time (350 ms by default) stops the base. As ros2_control does, the
loop thread alone runs SCHED_FIFO where the process may (root, CAP_SYS_NICE, or an
RLIMIT_RTPRIO high enough), with reset-on-fork set so that every thread it starts (a
re-configuration, a bus reconnect) runs at normal priority again; elsewhere a note says
once why not.

Memory is not locked (``mlockall``): in CPython every thread's 8 MB stack and every
mapped library would have to be resident (``MCL_CURRENT``), or every later allocation
locked or failing (``MCL_FUTURE``), for a loop whose pages stay warm by being touched
100 times a second; a robot computer without swap gains nothing from it.

What start-up allocated (the object dictionaries, the PDO maps, the libraries) is frozen
out of the collector (``gc.freeze``) once the base runs: a full collection then walks
only what was made since, not the whole program. Thawed when the last base closes, so
that what was frozen can be collected again.
"""

from __future__ import annotations

import gc
import logging
import os
import threading

logger = logging.getLogger("omnican.chassis")

_noted = False  # the "not permitted" note is said once per process
_note_lock = threading.Lock()


def _policy() -> int | None:
    return getattr(os, "SCHED_FIFO", None)


def policy_of(native_id: int) -> int:
    """The scheduling policy of thread ``native_id`` (0: the calling thread), without the
    reset-on-fork flag: ``os.SCHED_OTHER``, ``os.SCHED_FIFO``, ..."""
    return os.sched_getscheduler(native_id) & ~getattr(os, "SCHED_RESET_ON_FORK", 0)


def make_realtime(priority: int, native_id: int = 0) -> bool:
    """Run thread ``native_id`` (0: the calling thread) SCHED_FIFO at ``priority``
    (1-99), its children at normal priority. Returns whether it does; when the process
    may not (or the platform has no SCHED_FIFO), says why once per process and leaves the
    thread as it was. ``priority`` 0 asks for nothing."""
    if priority <= 0:
        return False
    why = realtime_refusal(priority, native_id)
    if why is not None:
        _note(why)
        return False
    logger.debug("control loop thread %d runs SCHED_FIFO %d", native_id or
                 threading.get_native_id(), priority)
    return True


def realtime_refusal(priority: int, native_id: int = 0) -> str | None:
    """:func:`make_realtime` without the note: None when thread ``native_id`` (0: the
    calling thread) now runs SCHED_FIFO at ``priority``, else why it does not (a phrase:
    "not permitted (run as root, ...)"). Other threads of a process that runs its control
    loop, or its simulated drives, at real-time priority take the same class with it."""
    fifo = _policy()
    if fifo is None or not hasattr(os, "sched_setscheduler"):
        return "this platform has no SCHED_FIFO"
    policy = fifo | getattr(os, "SCHED_RESET_ON_FORK", 0)
    try:
        os.sched_setscheduler(native_id, policy, os.sched_param(priority))
    except PermissionError:
        return ("not permitted (run as root, give the program CAP_SYS_NICE, or raise "
                f"RLIMIT_RTPRIO to {priority})")
    except OSError as exc:  # EINVAL: a kernel or container without real-time scheduling
        return f"refused: {exc.strerror or exc}"
    return None


def _note(why: str) -> None:
    global _noted
    with _note_lock:
        if _noted:
            return
        _noted = True
    logger.info("control loop at normal priority: real-time priority %s; "
                "chassis.rt_priority = 0 asks for none", why)


# ------------------------------------------------------------ the garbage collector

_frozen_by_us = 0  # open bases that froze the heap
_froze_first = False  # the permanent generation was ours (empty before): thaw it at the end
_gc_lock = threading.Lock()


def freeze_startup() -> None:
    """Move every object alive now out of the collector's reach (``gc.freeze``): a
    collection while the loop runs walks only what was made since."""
    global _frozen_by_us, _froze_first
    with _gc_lock:
        if _frozen_by_us == 0:
            _froze_first = gc.get_freeze_count() == 0
        _frozen_by_us += 1
        gc.freeze()


def thaw() -> None:
    """A base that froze closed: when it was the last, give the frozen objects back to
    the collector (unless someone else had frozen the heap before us)."""
    global _frozen_by_us
    with _gc_lock:
        if _frozen_by_us == 0:
            return
        _frozen_by_us -= 1
        if _frozen_by_us == 0 and _froze_first:
            gc.unfreeze()
