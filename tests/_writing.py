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


def interrupt_renders(monkeypatch, stop: list) -> list:
    """Count the frames a transfer renders (``rewrite_clip._ClipRenderer.part``, which a
    whole frame's render calls too, whichever thread renders which) into the list returned,
    and raise a Ctrl-C at the first frame at or past ``stop[0]`` (None: none); ``stop`` is a
    one-item list a test changes between its runs."""
    import facetransfer.rewrite_clip as rc

    real, calls = rc._ClipRenderer.part, []

    def counted(self, i):
        if stop[0] is not None and i >= stop[0]:
            raise KeyboardInterrupt
        calls.append(i)
        return real(self, i)

    monkeypatch.setattr(rc._ClipRenderer, "part", counted)
    return calls
