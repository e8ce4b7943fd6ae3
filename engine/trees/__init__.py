"""Surrogate trees (paper §4, Appendices A–B): surrogate fit, tree build, views, halos."""

from engine.trees.build import build_tree
from engine.trees.halos import SceneTrees, size_epsilon
from engine.trees.surrogates import DEFAULT_FIT, FITS, FitParameters
from engine.trees.tree import TREE_FORMAT, SurrogateTree, TreeStats

__all__ = [
    "DEFAULT_FIT",
    "FITS",
    "TREE_FORMAT",
    "FitParameters",
    "SceneTrees",
    "SurrogateTree",
    "TreeStats",
    "build_tree",
    "size_epsilon",
]
