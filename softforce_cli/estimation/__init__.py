"""Force sensing: contact intensities by quadratic programming and the per-frame loop."""
