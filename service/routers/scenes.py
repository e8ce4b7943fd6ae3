"""``/v1/scenes``: create, read, overwrite the state of, step and delete scenes."""

from __future__ import annotations

from typing import Annotated

from fastapi import APIRouter, Header, Request
from fastapi.responses import Response

from ..codecs import respond
from ..deps import Config, Engine, Held, Live, Meter, Owner, Storage, body, validated
from ..errors import Conflict, NotFound, Unprocessable
from ..idempotency import HEADER, keyed, replayed
from ..models import SceneSpec, SceneSummary, StateUpdate, StepAnswer, StepRequest
from ..openapi import documented
from ..scenes import LiveScene, apply_mesh_defaults, build_scene, pack_state, summary_of
from ..store import KeyTaken
from .meshes import known_mesh

router = APIRouter(prefix="/v1/scenes", tags=["scenes"])

IdempotencyKey = Annotated[
    str | None,
    Header(
        alias=HEADER,
        description="1-255 visible ASCII characters (a UUID): the request may be sent again"
        " safely; a repeat gets the first answer (Idempotent-Replayed: true)",
        json_schema_extra={"pattern": "^[!-~]{1,255}$"},
    ),
]


@router.post(
    "",
    status_code=201,
    summary="Create a scene of bodies (uploaded meshes) and planes",
    **documented(
        {201: (SceneSummary, "The scene, its state and each row's mass source and ε")},
        (400, 401, 404, 406, 409, 413, 415, 422),
        body=SceneSpec,
    ),
)
async def create_scene(
    request: Request,
    owner: Owner,
    settings: Config,
    store: Storage,
    engine: Engine,
    scenes: Live,
    held: Held,
    spec_in: Annotated[SceneSpec, body(SceneSpec)],
    idempotency_key: IdempotencyKey = None,
):
    """Bodies (``density`` or ``mass`` with optional ``inertia`` and ``center_of_mass``;
    ``epsilon`` a number or ``"auto"``), planes, gravity, ``dt``, ``scheme``, ``kernel``,
    ``max_halvings``, ``substeps`` (split a step that would move a body by more than its
    ε), ``separation_speed`` (m/s at which overlaps present when bodies are placed are let
    go; null: at once) and ``contact_model`` (``law``: paper, linear or hertz). Rows of the
    state: bodies, then planes. With an ``Idempotency-Key`` the request may be sent again
    safely (:mod:`service.idempotency`)."""
    raw = await request.body()
    rows = len(spec_in.bodies) + len(spec_in.planes)
    if rows > settings.max_bodies:
        raise Unprocessable(
            f"{rows:,} bodies and planes; this service takes <= {settings.max_bodies:,}"
        )
    async with keyed(request, owner, raw, store, engine, held) as (key, again):
        if again is not None:
            return again
        spec = spec_in.normalised()
        meshes = sorted({b["mesh"] for b in spec["bodies"]})
        apply_mesh_defaults(spec, {m: await known_mesh(engine, store, owner, m) for m in meshes})
        scene = await engine.run(
            "build_scene", build_scene, spec, store.tree, settings.engine_threads
        )
        scene_id = await engine.io(scenes.new_id)  # on a cluster: a started actor's
        live = LiveScene(scene, spec, 0)
        answer = summary_of(scene_id, live)
        remember = None if key is None else key.remember(201, answer.model_dump())
        try:
            gone = await engine.io(
                store.add_scene, owner, scene_id, spec, pack_state(scene), meshes, remember
            )
        except KeyTaken:  # stored by a request in another process meanwhile
            return await engine.io(replayed, request, store, owner, key)
        if gone:  # deleted while the scene was being built
            raise Conflict(
                f"mesh {gone[0]!r} was deleted while the scene was created; upload it again"
            )
        scenes.add(owner, scene_id, live)
    return await engine.io(respond, request, answer, 201)


@router.get(
    "/{scene_id}",
    summary="A scene and its state",
    **documented({200: (SceneSummary, "The scene")}, (401, 404, 406, 422, 503)),
)
async def get_scene(scene_id: str, request: Request, owner: Owner, engine: Engine, scenes: Live):
    answer = await engine.run("load_scene", scenes.summary, owner, scene_id)
    return await engine.io(respond, request, answer)


@router.put(
    "/{scene_id}/state",
    summary="Overwrite any of the state arrays",
    **documented(
        {200: (SceneSummary, "The scene, with overlaps when positions or orientations changed")},
        (400, 401, 404, 406, 409, 413, 415, 422, 503),
        body=StateUpdate,
    ),
)
async def put_state(
    scene_id: str,
    request: Request,
    owner: Owner,
    engine: Engine,
    scenes: Live,
    update: Annotated[StateUpdate, body(StateUpdate)],
):
    """Overwrite any of ``positions (n, 3)``, ``orientations (n, 4)``, ``velocities``,
    ``angular_velocities (n, 3)`` (n: bodies, then planes). The answer is the scene, with
    ``overlaps`` when positions or orientations were set (else null): ``pairs``, the body
    pairs whose surfaces now cross (overlap beyond the reach ε_a + ε_b), and ``largest``,
    the largest overlap of any contact relative to its pair's reach."""
    answer = await engine.run("set_state", scenes.put_state, owner, scene_id, update.given())
    return await engine.io(respond, request, answer)


@router.post(
    "/{scene_id}/step",
    summary="Step a scene",
    **documented(
        {200: (StepAnswer, "The new state and each step's statistics")},
        (400, 401, 404, 406, 409, 413, 415, 422, 503),
        body=StepRequest,
        body_required=False,
    ),
)
async def step_scene(
    scene_id: str,
    request: Request,
    owner: Owner,
    settings: Config,
    store: Storage,
    engine: Engine,
    scenes: Live,
    metrics: Meter,
    held: Held,
    idempotency_key: IdempotencyKey = None,
):
    """``{"steps": n, "dt"?}`` (no body: one step) → the new state and each step's
    statistics. The state is stored before the answer; a step that would leave a
    non-finite state is undone (422). With an ``Idempotency-Key`` header the request may be
    sent again safely: the answer is stored with the new state, in one transaction."""
    raw = await request.body()
    asked = (
        await engine.io(validated, StepRequest, raw, request.headers.get("content-type"))
        if raw
        else StepRequest()
    )
    if asked.steps > settings.max_steps:
        raise Unprocessable(
            f"steps must be <= {settings.max_steps} (MRDEM_MAX_STEPS), got {asked.steps}",
            errors=[{"path": "steps", "message": f"must be <= {settings.max_steps}"}],
        )
    async with keyed(request, owner, raw, store, engine, held) as (key, again):
        if again is not None:
            return again
        steps = asked.steps
        answer, stats = await engine.run("step", scenes.step, owner, scene_id, steps, asked.dt, key)
        if answer is None:
            return await engine.io(replayed, request, store, owner, key)
    metrics.steps.inc(steps)
    metrics.picard.inc(sum(s.picard_iterations for s in stats))
    metrics.comparisons.inc(sum(s.comparisons for s in stats))
    metrics.fallbacks.inc(sum(s.fallbacks for s in stats))
    return await engine.io(respond, request, answer)


@router.delete(
    "/{scene_id}",
    status_code=204,
    summary="Delete a scene",
    **documented({204: (None, "Deleted")}, (401, 404, 422)),
)
async def delete_scene(scene_id: str, owner: Owner, store: Storage, engine: Engine, scenes: Live):
    if not await engine.io(store.delete_scene, owner, scene_id):
        raise NotFound(f"no scene {scene_id!r}")
    scenes.drop(owner, scene_id)
    return Response(status_code=204)
