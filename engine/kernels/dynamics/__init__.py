"""Kernels of the dynamics: contact forces and the rigid-body motion update."""
