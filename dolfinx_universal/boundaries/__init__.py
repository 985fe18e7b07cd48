"""Immersed boundaries: the interface (``base``), curves (2D), surfaces (3D), their rigid
motions (``motions``) and domains of several components (``domains``)."""
