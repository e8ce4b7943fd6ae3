"""``/v1/scenes``: create, read, overwrite the state of, step and delete scenes."""

from __future__ import annotations

import dataclasses
import uuid

import numpy as np
from fastapi import APIRouter, Depends, Request
from fastapi.responses import Response

from ..auth import owner_of
from ..codecs import decode, respond
from ..errors import Conflict, NotFound, Unprocessable
from ..idempotency import keyed, replayed
from ..inputs import array, number
from ..scenes import (
    STATE,
    LiveScene,
    apply_mesh_defaults,
    build_scene,
    pack_state,
    parse_spec,
    restore_state,
    state_of,
)
from ..store import KeyTaken
from .meshes import known_mesh

router = APIRouter(prefix="/v1/scenes", tags=["scenes"])


@router.post("")
async def create_scene(request: Request, owner: str = Depends(owner_of)):
    """``{"bodies": [{"mesh", "position", "orientation", "velocity", "angular_velocity",
    "density" | "mass", "inertia" ((3, 3) or 3 principal moments; needs "mass"),
    "center_of_mass" (mesh frame; needs "mass"), "epsilon" (a number, or "auto"), "fixed"}],
    "planes": [{"point", "normal", "size"}], "gravity", "epsilon" (of the planes; absent:
    the default rule), "dt", "scheme", "kernel", "max_halvings", "substeps" (split a step
    that would move a body by more than its ε), "separation_speed" (m/s at which overlaps
    present when bodies are placed are let go; default 0.5, null: at once),
    "contact_model": {"law": "paper" | "linear" | "hertz", "stiffness", "damping",
    "friction", "slip_velocity", "tangential_stiffness" (k_t/k_n of the static-friction
    spring, default 2/7; 0: the regularised law)}}`` → 201 ``{"id", …, "mass_source",
    "epsilon"}`` (per row: bodies, then planes). With an ``Idempotency-Key`` header the
    request may be sent again safely (:mod:`service.idempotency`)."""
    state = request.app.state
    raw = await request.body()
    with keyed(request, owner, raw) as (key, again):
        if again is not None:
            return again
        body = decode(raw, request.headers.get("content-type"))
        spec = parse_spec(body, state.settings.max_bodies)
        meshes = sorted({b["mesh"] for b in spec["bodies"]})
        apply_mesh_defaults(spec, {m: known_mesh(request, owner, m) for m in meshes})
        scene = await state.engine.run(
            "build_scene", build_scene, spec, state.store.tree, state.settings.engine_threads
        )
        scene_id = uuid.uuid4().hex
        live = LiveScene(scene, spec, 0)
        answer = _summary(scene_id, live)
        remember = None if key is None else key.remember(201, answer)
        try:
            gone = state.store.add_scene(owner, scene_id, spec, pack_state(scene), meshes, remember)
        except KeyTaken:  # stored by a request in another process meanwhile
            return replayed(request, state.store, owner, key)
        if gone:  # deleted while the scene was being built
            raise Conflict(
                f"mesh {gone[0]!r} was deleted while the scene was created; upload it again"
            )
        state.scenes.add(owner, scene_id, live)
    return respond(request, answer, 201)


@router.get("/{scene_id}")
async def get_scene(scene_id: str, request: Request, owner: str = Depends(owner_of)):
    live = await _live(request, owner, scene_id)
    return respond(request, _summary(scene_id, live))


@router.put("/{scene_id}/state")
async def put_state(scene_id: str, request: Request, owner: str = Depends(owner_of)):
    """Overwrite any of ``positions (n, 3)``, ``orientations (n, 4)``, ``velocities``,
    ``angular_velocities (n, 3)`` (n: bodies, then planes). The answer is the scene, with
    ``overlaps`` when positions or orientations were set (else null): ``pairs``, the body
    pairs whose surfaces now cross (overlap beyond the reach ε_a + ε_b), and ``largest``,
    the largest overlap of any contact relative to its pair's reach."""
    state = request.app.state
    body = decode(await request.body(), request.headers.get("content-type"))
    if not isinstance(body, dict) or not set(body) & set(STATE):
        raise Unprocessable(f"body must be an object with any of {list(STATE)}")
    unknown = set(body) - set(STATE)
    if unknown:
        raise Unprocessable(f"unknown state fields {sorted(unknown)}; expected {list(STATE)}")
    live = await _live(request, owner, scene_id)
    n = len(live.scene)
    new = {k: array(v, k, (n, 4 if k == "orientations" else 3)) for k, v in body.items()}

    def apply():
        with live.lock:
            report = live.scene.set_state(**new)
            if not state.store.save_state(owner, scene_id, pack_state(live.scene), live.steps):
                raise NotFound(f"no scene {scene_id!r}")
            return report

    report = await state.engine.run("set_state", apply)
    overlaps = None
    if report is not None:
        overlaps = {"pairs": report.pairs.tolist(), "largest": report.largest}
    return respond(request, {**_summary(scene_id, live), "overlaps": overlaps})


@router.post("/{scene_id}/step")
async def step_scene(scene_id: str, request: Request, owner: str = Depends(owner_of)):
    """``{"steps": n, "dt"?}`` → the new state and each step's statistics. The state is
    stored before the answer; a step that would leave a non-finite state is undone (422).
    With an ``Idempotency-Key`` header the request may be sent again safely: the answer is
    stored with the new state, in one transaction (:mod:`service.idempotency`)."""
    state = request.app.state
    raw = await request.body()
    with keyed(request, owner, raw) as (key, again):
        if again is not None:
            return again
        body = decode(raw, request.headers.get("content-type")) if raw else {}
        if not isinstance(body, dict):
            raise Unprocessable("body must be an object")
        steps = number(body.get("steps", 1), "steps", 1, state.settings.max_steps, integer=True)
        live = await _live(request, owner, scene_id)
        dt = number(body.get("dt", live.spec["dt"]), "dt", 1e-12, 1.0)

        def run():
            with live.lock:
                scene = live.scene
                before = pack_state(scene)
                stats = []
                for k in range(steps):
                    stats.append(scene.step(dt))
                    if not all(np.isfinite(a).all() for a in state_of(scene).values()):
                        restore_state(scene, before)
                        raise Unprocessable(
                            f"step {k + 1} of {steps} left a non-finite state (the simulation"
                            " diverged); the scene keeps the state it had before this"
                            " request. Try a smaller dt or a softer contact model"
                        )
                answer = {
                    "id": scene_id,
                    "time": scene.time,
                    "steps": live.steps + steps,
                    "state": state_of(scene),
                    "stats": [dataclasses.asdict(s) for s in stats],
                }
                remember = None if key is None else key.remember(200, answer)
                try:
                    saved = state.store.save_state(
                        owner, scene_id, pack_state(scene), live.steps + steps, remember
                    )
                except KeyTaken:  # stored by a request in another process meanwhile
                    restore_state(scene, before)
                    return None, stats
                if not saved:
                    restore_state(scene, before)
                    raise NotFound(f"no scene {scene_id!r}")
                live.steps += steps
                return answer, stats

        answer, stats = await state.engine.run("step", run)
        if answer is None:
            return replayed(request, state.store, owner, key)
    m = state.metrics
    m.steps.inc(steps)
    m.picard.inc(sum(s.picard_iterations for s in stats))
    m.comparisons.inc(sum(s.comparisons for s in stats))
    m.fallbacks.inc(sum(s.fallbacks for s in stats))
    return respond(request, answer)


@router.delete("/{scene_id}", status_code=204)
async def delete_scene(scene_id: str, request: Request, owner: str = Depends(owner_of)):
    state = request.app.state
    if not state.store.delete_scene(owner, scene_id):
        raise NotFound(f"no scene {scene_id!r}")
    state.scenes.drop(owner, scene_id)
    return Response(status_code=204)


async def _live(request: Request, owner: str, scene_id: str) -> LiveScene:
    state = request.app.state
    return await state.engine.run("load_scene", state.scenes.get, owner, scene_id)


def _summary(scene_id: str, live: LiveScene) -> dict:
    spec = live.spec
    return {
        "id": scene_id,
        "bodies": len(spec["bodies"]),
        "planes": len(spec["planes"]),
        "time": live.scene.time,
        "steps": live.steps,
        "dt": spec["dt"],
        "scheme": spec["scheme"],
        "state": state_of(live.scene),
        "mass_source": live.scene.mass_source.tolist(),  # mesh | convex_hull | given | fixed
        "epsilon": live.scene.epsilon,  # each row's ε, after the default rule
        "spec": spec,
    }
