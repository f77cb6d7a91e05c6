"""Face tracking in monocular video (Vlasic et al. 2005, §5.1 tracking, §5.2 initialisation).

Modules: :mod:`.result` (the :class:`Track` result and its file), :mod:`.camera` (weak-perspective
pose, Eq. (7)), :mod:`.klt` (symmetric KLT terms, Eq. (6)), :mod:`.solver` (Eq. (8), (9)),
:mod:`.landmarks` (MediaPipe-478 to iBUG-68), :mod:`.init` (§5.2), :mod:`.tracker` (passes),
:mod:`.overlay` (drawing the fit on frames).
"""

from .result import Track

__all__ = ["Track"]
