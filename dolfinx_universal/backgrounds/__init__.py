"""Background meshes: uniform lattices and graded trees of acute cells."""
