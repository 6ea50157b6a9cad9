"""Real-time scheduling for the threads that must not wait: where the system allows it.

A thread of Linux's real-time class (SCHED_FIFO) runs as soon as it is ready, ahead of every
ordinary thread: a frame is not kept waiting while other work holds both cores. Such a
thread must sleep most of the time, as these do (they wait for frames and samples). Root
may use it; another user needs an rtprio limit (limits.conf) or CAP_SYS_NICE.
"""

from __future__ import annotations

import logging
import os

log = logging.getLogger(__name__)

NORMAL_PRIORITY = "normal"


def realtime_priority(thread_id: int, priority: int) -> str:
    """Schedule the thread `thread_id` (a native id; 0: the calling thread) as SCHED_FIFO at
    `priority` (0: leave it alone), where the system allows it; how it runs afterwards, in
    words (for the metadata and the bench). Threads it starts later inherit it."""
    if priority == 0:
        return NORMAL_PRIORITY
    try:
        os.sched_setscheduler(thread_id, os.SCHED_FIFO, os.sched_param(priority))
    except (AttributeError, OSError) as e:  # not Linux, or not permitted
        log.info("thread %d at normal priority: %s", thread_id, e)
        return f"{NORMAL_PRIORITY} (real-time priority not permitted)"
    return f"SCHED_FIFO {priority}"
