"""The installed environment is the one ``pyproject.toml`` declares.

MediaPipe requires ``opencv-contrib-python`` with no bound, and that wheel's ``cv2`` files
overwrite those of ``opencv-python-headless``: with only the headless line pinned, ``import cv2``
was OpenCV 5.1 while the project declares ``>=4.10,<5``. Every figure and test would then be of
an OpenCV the project does not claim to support.
"""

from __future__ import annotations

import re
import tomllib
from importlib import metadata
from pathlib import Path

import cv2
import pytest
from packaging.requirements import Requirement
from packaging.version import Version

PYPROJECT = Path(__file__).resolve().parents[1] / "pyproject.toml"
OPENCV_DISTRIBUTIONS = ("opencv-python-headless", "opencv-contrib-python", "opencv-python",
                        "opencv-contrib-python-headless")


def _requirements() -> dict[str, Requirement]:
    deps = tomllib.loads(PYPROJECT.read_text())["project"]["dependencies"]
    return {r.name: r for r in map(Requirement, deps)}


def _cv2_version() -> Version:
    """OpenCV's own version (``cv2.__version__``, e.g. ``4.14.0`` or ``5.1.0-dev``)."""
    return Version(re.match(r"\d+(\.\d+)*", cv2.__version__).group(0))


def test_imported_opencv_is_the_declared_one():
    spec = _requirements()["opencv-python-headless"].specifier
    assert spec.contains(_cv2_version()), (
        f"import cv2 gives OpenCV {cv2.__version__}; pyproject.toml declares {spec}")


def test_every_installed_opencv_wheel_is_in_the_declared_range():
    """Each OpenCV wheel present (MediaPipe brings the contrib one) is in the declared range,
    so whichever was installed last, ``cv2`` is in it."""
    spec = _requirements()["opencv-python-headless"].specifier
    present = []
    for name in OPENCV_DISTRIBUTIONS:
        try:
            version = Version(metadata.version(name))
        except metadata.PackageNotFoundError:
            continue
        present.append(name)
        assert spec.contains(version), f"{name} {version} is installed, outside {spec}"
    if not present:
        pytest.fail("no OpenCV wheel is installed")


def test_mediapipes_opencv_is_bounded_as_the_declared_one():
    reqs = _requirements()
    assert "opencv-contrib-python" in reqs
    assert str(reqs["opencv-contrib-python"].specifier) == str(
        reqs["opencv-python-headless"].specifier)
