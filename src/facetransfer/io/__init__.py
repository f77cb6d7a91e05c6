"""File input and output: video and image-sequence plates (read, written, their headers and
colour), meshes, landmarks, npz archives, atomic writes and the frame memory budget.

The project's own files (tracks, models, exports, manifests) are read and written by the
modules that define them; README's "Architecture" lists this package's modules.
"""
