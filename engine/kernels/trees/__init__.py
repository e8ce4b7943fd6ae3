"""Kernels of the surrogate trees: the Appendix-A fit and the level-synchronous build."""
