"""Work done ahead on threads, handed out in order: the frame files of a sequence decoded while
the frames before them are used, a plate's frames graded while the ones before them are
written."""

from __future__ import annotations

import os
from collections import deque
from collections.abc import Callable, Iterable, Iterator

__all__ = ["ordered_ahead"]


def ordered_ahead(fn: Callable, items: Iterable, *, ahead: int,
                  workers: int | None = None) -> Iterator:
    """``fn(*item)`` for each of ``items`` in turn, the next ``ahead`` computed meanwhile by a
    pool of threads (default: as many as cores, at most 4); worth it where ``fn`` releases the
    GIL (OpenCV's codecs, numpy's large operations). Items not yet computed when the consumer
    stops are cancelled."""
    from concurrent.futures import ThreadPoolExecutor

    n = workers if workers is not None else max(1, min(4, os.cpu_count() or 1))
    with ThreadPoolExecutor(max_workers=n) as pool:
        pending = deque()
        try:
            for item in items:
                pending.append(pool.submit(fn, *item))
                if len(pending) > ahead:
                    yield pending.popleft().result()
            while pending:
                yield pending.popleft().result()
        finally:
            for fut in pending:
                fut.cancel()
