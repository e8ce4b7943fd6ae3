"""Collision: broad phase, contact search (flat, multiresolution, batch, multiscale), proximity."""

from engine.collision.batch import ContactBatch, TreeBank, find_contacts_batch
from engine.collision.broadphase import candidate_pairs
from engine.collision.contacts import ContactSet, ContactStats, find_contacts
from engine.collision.pair_cache import PairCache
from engine.collision.proximity import MeshDistance, mesh_distance

__all__ = [
    "ContactBatch",
    "ContactSet",
    "ContactStats",
    "MeshDistance",
    "PairCache",
    "TreeBank",
    "candidate_pairs",
    "find_contacts",
    "find_contacts_batch",
    "mesh_distance",
]
