"""Triangle meshes as fluid colliders: the checks a mesh must pass and MuJoCo's convex hull.

A mesh collider's signed distance takes its sign from the faces' winding, so only a closed,
outward-wound mesh has an inside. An open mesh (a tray modelled as five faces, a single
wall) has none: near its boundary the sign flips, and a particle found "inside" is pushed
to the far side in one step. :func:`check_closed_mesh` rejects such meshes, and MuJoCo mesh
geoms become colliders through :func:`convex_hull`, the same shape MuJoCo's own contacts use
(a concave or open mesh geom collides as its hull in MuJoCo; build a container from convex
pieces or a container shell to hold liquid).
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import ConvexHull, QhullError

from pourbench.errors import InvalidParameterError


def check_closed_mesh(vertices: np.ndarray, triangles: np.ndarray) -> None:
    """Raise :class:`InvalidParameterError` unless the mesh is closed and wound outward.

    Closed and consistently wound: every directed edge (a, b) of a triangle appears exactly
    once, and its reverse (b, a) once. Outward: the enclosed signed volume is positive.
    """
    v = np.asarray(vertices, float)
    t = np.asarray(triangles)
    if v.ndim != 2 or v.shape[1] != 3 or len(v) < 4 or not np.all(np.isfinite(v)):
        raise InvalidParameterError(
            f"mesh vertices must be a finite (n >= 4, 3) array, got shape {v.shape}"
        )
    if t.ndim != 2 or t.shape[1] != 3 or len(t) < 4 or not np.issubdtype(t.dtype, np.integer):
        raise InvalidParameterError(
            f"mesh triangles must be an integer (m >= 4, 3) array, got {t.dtype} {t.shape}"
        )
    if t.min() < 0 or t.max() >= len(v):
        raise InvalidParameterError(
            f"mesh triangles index vertices {t.min()}..{t.max()}, but there are {len(v)}"
        )
    directed = np.concatenate([t[:, [0, 1]], t[:, [1, 2]], t[:, [2, 0]]])
    pairs, counts = np.unique(directed, axis=0, return_counts=True)
    forward = {tuple(p) for p in pairs}
    repeated = int(np.count_nonzero(counts > 1))
    unmatched = sum((b, a) not in forward for a, b in forward)
    if repeated or unmatched:
        raise InvalidParameterError(
            f"mesh is not closed and consistently wound: {unmatched} edge(s) have no opposite "
            f"edge and {repeated} are repeated in the same direction, so it has no inside; "
            "use pourbench.fluids.meshes.convex_hull(vertices) or a container shell"
        )
    a, b, c = v[t[:, 0]], v[t[:, 1]], v[t[:, 2]]
    volume = float(np.einsum("ij,ij->i", a, np.cross(b, c)).sum()) / 6.0
    if volume <= 0.0:
        raise InvalidParameterError(
            f"mesh faces are wound inward (enclosed signed volume {volume:.3g} m^3); "
            "reverse each triangle's vertex order"
        )


def convex_hull(vertices: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The convex hull of ``vertices`` as (hull vertices (k, 3), outward triangles (m, 3))."""
    v = np.asarray(vertices, float)
    try:
        hull = ConvexHull(v)
    except QhullError as err:  # flat or degenerate point sets have no volume
        raise InvalidParameterError(f"mesh has no convex hull with volume: {err}") from None
    used = np.unique(hull.simplices)
    remap = np.full(len(v), -1)
    remap[used] = np.arange(len(used))
    tris = remap[hull.simplices]
    pts = v[used]
    # Qhull's facet equations give each triangle's outward normal: wind to agree with it
    a, b, c = pts[tris[:, 0]], pts[tris[:, 1]], pts[tris[:, 2]]
    inward = np.einsum("ij,ij->i", np.cross(b - a, c - a), hull.equations[:, :3]) < 0
    tris[inward] = tris[inward][:, ::-1]
    return pts, tris.astype(np.int32)
