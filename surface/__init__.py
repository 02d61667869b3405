"""photosurf.surface: 3D points to a smooth surface.

Knows geometry; knows nothing of images.
"""
