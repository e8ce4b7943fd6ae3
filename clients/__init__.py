"""mrdem client library (httpx): meshes, contacts and remote simulation loops over HTTP.
Imports neither engine nor service; speaks msgpack (arrays as typed binary) by default."""

from .aio import AsyncClient, AsyncRemoteScene
from .errors import BuildFailed, BuildTimeout, ClientError, ProblemError, ServiceUnreachable
from .models import BuildJob, ContactResult, Contacts, MeshInfo, Overlaps, SceneState
from .sync import Client, RemoteScene

__all__ = [
    "AsyncClient",
    "AsyncRemoteScene",
    "BuildFailed",
    "BuildJob",
    "BuildTimeout",
    "Client",
    "ClientError",
    "ContactResult",
    "Contacts",
    "MeshInfo",
    "Overlaps",
    "ProblemError",
    "RemoteScene",
    "SceneState",
    "ServiceUnreachable",
]
