"""File input and output: the only code that touches files (meshes, landmarks, video, atomic writes)."""
