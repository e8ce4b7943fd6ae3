"""mrdem client library (httpx): meshes, contacts and remote simulation loops over HTTP.
Imports neither engine nor service; speaks msgpack (arrays as typed binary) by default."""

from .aio import AsyncClient, AsyncRemoteScene
from .errors import ClientError, ProblemError, ServiceUnreachable
from .models import ContactResult, Contacts, MeshInfo, SceneState
from .sync import Client, RemoteScene

__all__ = [
    "AsyncClient",
    "AsyncRemoteScene",
    "Client",
    "ClientError",
    "ContactResult",
    "Contacts",
    "MeshInfo",
    "ProblemError",
    "RemoteScene",
    "SceneState",
    "ServiceUnreachable",
]
