"""What the tests of the writers that outlive an interruption share (``video_parts``,
``sequence_parts``)."""

from __future__ import annotations


def write_rest(writer, frames, *, stop=None, marked=lambda i: False) -> int:
    """Write ``frames`` from the writer's :attr:`done` on, inside the writer's context (kept on
    an error, committed otherwise); a Ctrl-C before frame ``stop``. Returns where it started."""
    start = writer.done
    with writer:
        for i in range(start, len(frames)):
            if i == stop:
                raise KeyboardInterrupt
            writer.write(frames[i], marked=marked(i))
    return start
