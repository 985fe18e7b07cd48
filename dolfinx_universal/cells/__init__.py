"""What differs by cell type: triangle and tetrahedron geometry, picked through one kit."""
