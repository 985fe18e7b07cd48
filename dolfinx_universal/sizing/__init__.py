"""Mesh sizes: from the geometry (local feature size) and from the user (size fields)."""
