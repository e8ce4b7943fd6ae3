"""Surrogate trees (paper §4, Appendix A–B): the surrogate fit, the tree build and its halos."""

from engine.trees.halos import SceneTrees
from engine.trees.surrogates import DEFAULT_FIT, FITS, FitParameters
from engine.trees.tree import TREE_FORMAT, SurrogateTree, TreeStats, build_tree

__all__ = [
    "DEFAULT_FIT",
    "FITS",
    "TREE_FORMAT",
    "FitParameters",
    "SceneTrees",
    "SurrogateTree",
    "TreeStats",
    "build_tree",
]
