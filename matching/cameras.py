"""Cameras and their files under one name: the model and the five file formats.

The camera model (:class:`Camera`, :class:`StereoRig`, turned images, quaternions) is
:mod:`matching.camera_model`; the files (cameras.yml, OpenCV stereo calibration, COLMAP
text and binary models, projection matrices, and :func:`read_cameras` for any of them) are
:mod:`matching.camera_files`.  This module re-exports both, so that a caller that needs a
camera and its file imports one module.
"""

from __future__ import annotations

from matching import camera_files, camera_model
from matching.camera_files import *  # noqa: F403
from matching.camera_model import *  # noqa: F403

__all__ = [*camera_model.__all__, *camera_files.__all__]
