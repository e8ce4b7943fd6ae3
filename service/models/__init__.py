"""The HTTP boundary's models: every request body and every answer of the ``/v1`` API,
and the problem details of its errors. JSON and msgpack bodies decode to the same Python
values and validate through the same models (:mod:`service.models.arrays` types the
arrays)."""

from .arrays import QUATERNION_TOLERANCE, Shape
from .contacts import (
    CONTACTS_QUERY,
    ColumnarContacts,
    ColumnarQuery,
    ContactsQuery,
    ContactStatsOut,
    PairContacts,
    PerPairContacts,
    PerPairQuery,
)
from .meshes import (
    MAX_BRANCHING,
    BuildJob,
    JobList,
    MeshFacts,
    MeshForm,
    MeshList,
    MeshUpload,
    SurrogateLevel,
)
from .problems import FieldError, Problem, field_errors, path_text
from .scenes import (
    LAWS,
    STATE,
    SceneSpec,
    SceneSummary,
    StateUpdate,
    StepAnswer,
    StepRequest,
)

__all__ = [
    "CONTACTS_QUERY",
    "LAWS",
    "MAX_BRANCHING",
    "QUATERNION_TOLERANCE",
    "STATE",
    "BuildJob",
    "ColumnarContacts",
    "ColumnarQuery",
    "ContactStatsOut",
    "ContactsQuery",
    "FieldError",
    "JobList",
    "MeshFacts",
    "MeshForm",
    "MeshList",
    "MeshUpload",
    "PairContacts",
    "PerPairContacts",
    "PerPairQuery",
    "Problem",
    "SceneSpec",
    "SceneSummary",
    "Shape",
    "StateUpdate",
    "StepAnswer",
    "StepRequest",
    "SurrogateLevel",
    "field_errors",
    "path_text",
]
