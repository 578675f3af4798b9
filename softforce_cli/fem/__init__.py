"""Finite element core: pure, vectorised functions on numpy arrays (numpy/scipy only)."""
