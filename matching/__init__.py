"""photosurf.matching: images and cameras to 3D points.

Knows cameras and pixels; knows nothing of sections or meshes.
"""
