"""File input and output: video and image-sequence plates (read, written, their headers and
colour), meshes, landmarks, npz archives, atomic writes and the frame memory budget.

The project's own files (tracks, models, exports, manifests) are read and written by the
modules that define them; README's "Architecture" lists this package's modules. Its file
primitives (:mod:`.atomic`, :mod:`.npz`, :mod:`.mesh`, :mod:`.output_names`, :mod:`.verified`,
:mod:`.memory`) sit in the layer below the rest, with the models and data sets that write and
read with them; the frames' modules above (``LAYER_OF`` in ``tests/test_architecture.py``).
This file, which Python runs before any of them, imports nothing.
"""
