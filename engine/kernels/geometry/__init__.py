"""Kernels of the geometry: triangle distances (exact, iterative, batched), vertex welding."""
