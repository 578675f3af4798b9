"""Reduced-order models of the FE model: POD basis, ECSW hyper-reduction, .rom.npz files."""
