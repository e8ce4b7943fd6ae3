"""Kernels of the collision search: broad phase, rigid set-up, traversal, batches, merging."""
