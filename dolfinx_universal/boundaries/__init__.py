"""Immersed boundaries: curves (2D) and surfaces (3D), their motions and domains."""
