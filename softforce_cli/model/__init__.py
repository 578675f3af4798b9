"""Robot model: mesh, material, boundary conditions, cables, features and markers."""
