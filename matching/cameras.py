"""Cameras and their files under one name: the model and the five file formats.

The camera model (:class:`Camera`, :class:`StereoRig`, turned images, quaternions) is
:mod:`matching.camera_model`; the files (cameras.yml, OpenCV stereo calibration, COLMAP
text and binary models, projection matrices, and :func:`read_cameras` for any of them) are
:mod:`matching.camera_files`.  This module re-exports both, so that a caller that needs a
camera and its file imports one module.
"""

from __future__ import annotations

from matching.camera_files import (
    cameras_from_pycolmap,
    read_cameras,
    read_cameras_yml,
    read_colmap,
    read_colmap_text,
    read_projection_txt,
    read_rig,
    read_stereo_calibration,
    write_cameras_yml,
    write_colmap_text,
    write_rig,
)
from matching.camera_model import (
    Camera,
    StereoRig,
    quaternion_to_rotation,
    rotation_to_quaternion,
    turn_camera,
)

__all__ = [
    "Camera",
    "StereoRig",
    "write_cameras_yml",
    "read_cameras_yml",
    "write_rig",
    "read_rig",
    "read_stereo_calibration",
    "write_colmap_text",
    "read_colmap_text",
    "read_colmap",
    "cameras_from_pycolmap",
    "read_projection_txt",
    "read_cameras",
    "rotation_to_quaternion",
    "quaternion_to_rotation",
    "turn_camera",
]
