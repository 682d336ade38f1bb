"""Look at a MuJoCo scene: a rerun recording (``.rrd``) of its geoms, or MuJoCo's viewer.

Rerun has no MuJoCo loader, so geoms are turned into triangle meshes here: mesh geoms from the
compiled model's vertices and faces, primitives (plane, sphere, capsule, cylinder, box) from a
small hand-written tessellation.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Iterable, Iterator, Mapping, Sequence
from pathlib import Path

import mujoco
import numpy as np

from pourbench.errors import InvalidParameterError, PourbenchError, check_index
from pourbench.outputs import AtomicOutput

_RINGS, _SEGMENTS = 8, 16


def check_display(
    environ: Mapping[str, str] | None = None,
    platform: str | None = None,
    asked: str = "--viewer",
    instead: str = "leave --viewer out to write a rerun recording instead",
) -> None:
    """Raise a clear error when MuJoCo's (GLFW) viewer has no display to open on Linux: what
    was ``asked`` needs one, do what ``instead`` says.

    Without this, GLFW fails after MuJoCo has written its error to ``MUJOCO_LOG.TXT`` in the
    working directory.
    """
    environ = os.environ if environ is None else environ
    if not (sys.platform if platform is None else platform).startswith("linux"):
        return
    if environ.get("DISPLAY") or environ.get("WAYLAND_DISPLAY"):
        return
    raise PourbenchError(
        f"{asked} needs a display (neither DISPLAY nor WAYLAND_DISPLAY is set); {instead}"
    )


def _sphere(radius: float, half_length: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """UV sphere (a capsule when ``half_length`` > 0), axis z: vertices, triangles."""
    lat = np.linspace(0.0, np.pi, _RINGS + 2)[1:-1]  # no ring on the equator
    lon = np.linspace(0.0, 2 * np.pi, _SEGMENTS, endpoint=False)
    ring = np.stack(
        [
            np.outer(np.sin(lat), np.cos(lon)).ravel(),
            np.outer(np.sin(lat), np.sin(lon)).ravel(),
            np.repeat(np.cos(lat), _SEGMENTS),
        ],
        axis=1,
    )
    verts = np.concatenate([[[0, 0, 1.0]], ring, [[0, 0, -1.0]]]) * radius
    verts[:, 2] += np.sign(verts[:, 2]) * half_length
    tris = []
    n = _SEGMENTS
    for j in range(n):
        tris.append((0, 1 + j, 1 + (j + 1) % n))
        last = 1 + (_RINGS - 1) * n
        tris.append((len(verts) - 1, last + (j + 1) % n, last + j))
    for r in range(_RINGS - 1):
        a, b = 1 + r * n, 1 + (r + 1) * n
        for j in range(n):
            k = (j + 1) % n
            tris += [(a + j, b + j, b + k), (a + j, b + k, a + k)]
    return verts, np.array(tris)


def _cylinder(radius: float, half_length: float) -> tuple[np.ndarray, np.ndarray]:
    lon = np.linspace(0.0, 2 * np.pi, _SEGMENTS, endpoint=False)
    circle = np.stack([np.cos(lon), np.sin(lon)], axis=1) * radius
    n = _SEGMENTS
    verts = np.concatenate(
        [
            np.column_stack([circle, np.full(n, half_length)]),
            np.column_stack([circle, np.full(n, -half_length)]),
            [[0, 0, half_length], [0, 0, -half_length]],
        ]
    )
    tris = []
    for j in range(n):
        k = (j + 1) % n
        tris += [(j, n + j, n + k), (j, n + k, k), (2 * n, j, k), (2 * n + 1, n + k, n + j)]
    return verts, np.array(tris)


def _box(half: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    corners = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], float)
    faces = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    tris = [t for a, b, c, d in faces for t in ((a, b, c), (a, c, d))]
    return corners * half, np.array(tris)


def geom_mesh(model: mujoco.MjModel, g: int) -> tuple[np.ndarray, np.ndarray] | None:
    """Vertices (in the geom frame, m) and triangles of geom ``g``; None for unsupported types.

    Raises:
        InvalidParameterError: ``g`` is not an index in ``[0, model.ngeom)``.
    """
    g = check_index("geom index g", g, model.ngeom)
    t, size = model.geom_type[g], model.geom_size[g]
    if t == mujoco.mjtGeom.mjGEOM_MESH:
        m = model.geom_dataid[g]
        v0, nv = model.mesh_vertadr[m], model.mesh_vertnum[m]
        f0, nf = model.mesh_faceadr[m], model.mesh_facenum[m]
        return model.mesh_vert[v0 : v0 + nv].astype(float), model.mesh_face[f0 : f0 + nf]
    if t == mujoco.mjtGeom.mjGEOM_PLANE:
        hx, hy = (s if s > 0 else 5.0 for s in size[:2])
        return _box(np.array([hx, hy, 0.0]))
    if t == mujoco.mjtGeom.mjGEOM_SPHERE:
        return _sphere(size[0])
    if t == mujoco.mjtGeom.mjGEOM_CAPSULE:
        return _sphere(size[0], size[1])
    if t == mujoco.mjtGeom.mjGEOM_CYLINDER:
        return _cylinder(size[0], size[1])
    if t == mujoco.mjtGeom.mjGEOM_BOX:
        return _box(size)
    return None


def _check_data(model: mujoco.MjModel, data: mujoco.MjData, *, finite: bool = False) -> None:
    """Refuse ``data`` of another model (its arrays would be read out of bounds) and, with
    ``finite``, geom poses that are not finite."""
    if not isinstance(model, mujoco.MjModel) or not isinstance(data, mujoco.MjData):
        raise InvalidParameterError(
            f"need a mujoco.MjModel and its mujoco.MjData, got {type(model).__name__} and "
            f"{type(data).__name__}"
        )
    if (
        data.qpos.size != model.nq
        or data.geom_xpos.shape[0] != model.ngeom
        or data.xpos.shape[0] != model.nbody
    ):
        raise InvalidParameterError(
            f"data does not belong to model: it has {data.qpos.size} qpos, "
            f"{data.geom_xpos.shape[0]} geoms and {data.xpos.shape[0]} bodies, the model "
            f"{model.nq}, {model.ngeom} and {model.nbody}"
        )
    if finite and not (np.isfinite(data.geom_xpos).all() and np.isfinite(data.geom_xmat).all()):
        raise InvalidParameterError("data has non-finite geom poses (NaN qpos?); nothing recorded")


def local_meshes(
    model: mujoco.MjModel, groups: Sequence[int] = (0, 1, 2)
) -> Iterator[tuple[int, str, np.ndarray, np.ndarray, np.ndarray]]:
    """(geom id, "body/geom" name, vertices in the geom's frame, triangles, rgba) of every
    geom in ``groups`` that has a mesh (:func:`geom_mesh`)."""
    for g in range(model.ngeom):
        if model.geom_group[g] not in groups:
            continue
        mesh = geom_mesh(model, g)
        if mesh is None:
            continue
        verts, tris = mesh
        body = model.body(model.geom_bodyid[g]).name or f"body_{model.geom_bodyid[g]}"
        name = model.geom(g).name or f"geom_{g}"
        rgba = model.geom_rgba[g]
        if model.geom_matid[g] >= 0:
            rgba = model.mat_rgba[model.geom_matid[g]]
        yield g, f"{body}/{name}", verts, tris, rgba


def world_meshes(
    model: mujoco.MjModel, data: mujoco.MjData, groups: Sequence[int] = (0, 1, 2)
) -> Iterator[tuple[str, np.ndarray, np.ndarray, np.ndarray]]:
    """(entity path, world vertices, triangles, rgba) of every geom in ``groups``.

    Raises:
        InvalidParameterError: ``data`` was not made for ``model``, or ``groups`` not integers.
    """
    _check_data(model, data)
    groups = list(groups) if isinstance(groups, Iterable) else groups
    if not isinstance(groups, list) or not all(
        isinstance(x, int | np.integer) and not isinstance(x, bool) for x in groups
    ):
        raise InvalidParameterError(f"groups must be a sequence of integers, got {groups!r}")
    for g, name, verts, tris, rgba in local_meshes(model, groups):
        world = data.geom_xpos[g] + verts @ data.geom_xmat[g].reshape(3, 3).T
        yield f"scene/{name}", world, tris, rgba


def record(model: mujoco.MjModel, data: mujoco.MjData, path: str | Path) -> Path:
    """Write the scene's geoms at ``data``'s pose to a rerun recording at ``path``.

    Raises:
        InvalidParameterError: ``data`` was not made for ``model``, or its geom poses are not
            finite; nothing is written then.
    """
    _check_data(model, data, finite=True)
    import rerun as rr

    out = AtomicOutput(path)
    rec = rr.RecordingStream("pourbench")
    rec.save(str(out.partial))
    try:
        rec.log("scene", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        for entity, verts, tris, rgba in world_meshes(model, data):
            colour = (np.clip(rgba, 0, 1) * 255).astype(np.uint8)
            rec.log(
                entity,
                rr.Mesh3D(vertex_positions=verts, triangle_indices=tris, albedo_factor=colour),
                static=True,
            )
        rec.flush()
    except BaseException:  # a failed recording leaves an earlier one at ``path`` as it was
        rec.disconnect()
        out.discard()
        raise
    rec.disconnect()
    return out.commit()
