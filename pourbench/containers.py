"""The container family: ``assets/containers.toml`` -> fluid colliders and MuJoCo bodies.

Each entry of the TOML file becomes a :class:`Container` whose ``shape`` is the fluid solver's
signed-distance collider (a :mod:`pourbench.geometry.shapes` object). :func:`add_container_body`
builds the MuJoCo body from the *same* shape: the revolved wall is the union, over the profile's
segments, of 2-D "stadiums" (all points within half the wall thickness of the segment — exactly
the SDF's wall), each revolved in angular sectors into convex mesh pieces. Arc vertices are
pushed out so chords straddle the true surface; the pieces' boundary stays within
``max_error`` of the SDF's zero level set. Hand-written: no library builds thin revolved shells
out of convex pieces.

Frames: a container's body frame is its shape frame (origin at the centre of the outer bottom,
+z out of the mouth). The ``<name>_mount`` site sits on the outside of the wall at
``grasp_height`` with +z pointing at the axis (the gripper's approach) and +x along the
container's +z, so a gripper whose end-effector frame matches it holds the container upright.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass
from functools import cache
from importlib import resources
from pathlib import Path

import mujoco
import numpy as np
from scipy.spatial import ConvexHull

from pourbench.errors import (
    InvalidParameterError,
    ProfileFileError,
    UnknownNameError,
    check_array,
    check_finite,
    check_quat,
    read_toml,
)
from pourbench.geometry.shapes import (
    BoxShell,
    ContainerShape,
    RevolvedShell,
    bottle,
    bowl,
    cup,
    tray,
)

ROLES: tuple[str, ...] = ("training", "novel", "receiving")
KINDS: dict[str, tuple[str, ...]] = {
    "cup": ("radius", "depth", "wall"),
    "bowl": ("radius", "depth", "wall"),
    "bottle": ("radius", "body_height", "neck_radius", "neck_height", "shoulder_height", "wall"),
    "tray": ("radius", "depth", "wall"),
    "profile": ("points", "wall"),
}
_COMMON = ("role", "kind", "mass", "grasp_height", "rgba", "description")

CONTAINER_CONTYPE = 4
"""Contact bit of container geoms: they touch static geoms (bit 1) and each other, not robots."""
CONTAINER_CONAFFINITY = 5

DEFAULT_MAX_ERROR = 2.0e-4
"""Largest distance (m) between the MuJoCo pieces' surface and the SDF's zero level set."""

MIN_MAX_ERROR = 1.0e-5
"""Smallest accepted ``max_error``, m: the finest mesh a shipped container gets at it (the
bowl, 1728 pieces) builds and compiles in about 1.5 s; 1e-6 took 15 s, 1e-9 several minutes."""

MAX_WALL_PIECES = 2048
"""Most convex pieces one container body may have (about 2 s to build and compile)."""
MAX_WALL_VERTICES = 150_000
"""Most mesh vertices, over all pieces, one container body may have (about 2 s)."""
MAX_ARC_STEPS = 64
"""Most chords on the rounded rim of one wall segment: more makes Qhull fail on the pieces."""

MIN_WALL = 1.0e-4
"""Thinnest accepted wall, m (0.1 mm; the shipped walls are 1.5 to 6 mm): Qhull cannot hull
the pieces of a much thinner one."""
MAX_SIZE = 2.0
"""Largest accepted outer diameter and rim height of a container file's entry, m."""

DEFAULT_PATH = Path(str(resources.files("pourbench") / "assets" / "containers.toml"))


@dataclass(frozen=True)
class Container:
    """One container: its fluid collider plus what MuJoCo and the policy need.

    Attributes:
        name: key in ``containers.toml``.
        role: "training", "novel" or "receiving".
        kind: how the TOML entry describes the wall (see :data:`KINDS`).
        shape: the fluid solver's signed-distance collider.
        mass: kg.
        grasp_height: height of the ``<name>_mount`` site above the outer bottom, m.
        rgba: colour.
        description: what it models.
    """

    name: str
    role: str
    kind: str
    shape: ContainerShape
    mass: float
    grasp_height: float
    rgba: tuple[float, float, float, float]
    description: str

    @property
    def wall(self) -> float:
        """Wall thickness, m."""
        return self.shape.wall

    @property
    def interior_volume(self) -> float:
        """Cavity volume up to the rim, m^3."""
        return self.shape.interior_volume

    @property
    def rim_height(self) -> float:
        """Height of the rim (wall mid-surface) above the outer bottom, m."""
        return self.shape.rim_height

    @property
    def depth(self) -> float:
        """Inner depth, from the inside of the bottom to the rim, m (observed by the policy)."""
        return self.shape.rim_height - self.shape.bottom_z

    @property
    def diameter(self) -> float:
        """Largest outer diameter, m (observed by the policy)."""
        return 2.0 * _outer_radius_max(self.shape)

    @property
    def mouth_diameter(self) -> float:
        """Inner diameter at the rim, m."""
        if isinstance(self.shape, BoxShell):
            return 2.0 * min(self.shape.half_x, self.shape.half_y)
        return 2.0 * self.shape.mouth_radius

    def mount_pose(self) -> tuple[np.ndarray, np.ndarray]:
        """Pose of the ``<name>_mount`` site in the container frame: position (m), quaternion."""
        z = self.grasp_height
        if isinstance(self.shape, BoxShell):
            r = self.shape.half_x + self.shape.wall
        else:
            pts = self.shape.points
            r = float(np.interp(z, pts[1:, 1], pts[1:, 0])) + self.shape.wall / 2
        # columns: x = container +z, y = +y, z = -x (towards the axis)
        rot = np.array([[0.0, 0.0, -1.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0]])
        quat = np.zeros(4)
        mujoco.mju_mat2Quat(quat, rot.ravel())
        return np.array([r, 0.0, z]), quat

    def wall_pieces(self, max_error: float = DEFAULT_MAX_ERROR) -> list[np.ndarray]:
        """Convex pieces whose union is the wall, each an (n, 3) vertex array in m;
        ``max_error`` bounds the distance between their surface and the SDF's zero level set, m.

        Raises:
            InvalidParameterError: ``max_error`` not a finite number >= :data:`MIN_MAX_ERROR`, a
                wall thinner than :data:`MIN_WALL`, or more pieces than :data:`MAX_WALL_PIECES`
                (or vertices than :data:`MAX_WALL_VERTICES`).
        """
        return _wall_pieces(self.shape, max_error, f"container {self.name!r}")


def _outer_radius_max(shape: ContainerShape) -> float:
    if isinstance(shape, BoxShell):
        return math.hypot(shape.half_x, shape.half_y) + shape.wall
    return shape.outer_radius


def _arc_steps(radius: float, max_error: float, span: float) -> int:
    """Chords needed over ``span`` rad of a circle so straddling chords err < ``max_error``."""
    if radius <= max_error:
        return 1
    # straddled chord of angle delta errs radius * tan^2(delta / 4)
    delta = 4.0 * math.atan(math.sqrt(max_error / radius))
    return max(1, math.ceil(span / delta))


def _stadium(a: np.ndarray, b: np.ndarray, h: float, steps: int) -> np.ndarray:
    """Convex polygon (k, 2) of the points within ``h`` of segment ab, arcs straddled."""
    t = b - a
    t = t / np.linalg.norm(t)
    n = np.array([-t[1], t[0]])
    psi = np.linspace(0.0, math.pi, steps + 1)
    scale = np.full(steps + 1, 2.0 / (1.0 + math.cos(math.pi / steps / 2)))
    scale[[0, -1]] = 1.0  # the straight sides are exact
    arc = (h * scale)[:, None] * (np.cos(psi)[:, None] * n + np.sin(psi)[:, None] * t)
    poly = np.concatenate([b + arc, a - arc])
    poly[:, 0] = np.maximum(poly[:, 0], 0.0)  # the half-plane rho >= 0 is all that revolves
    return poly


def _wall_plan(shape: ContainerShape, max_error: object, who: str) -> tuple[int, int]:
    """(sectors, arc steps) of ``shape``'s wall pieces, after checking ``max_error`` and that
    the pieces stay within :data:`MAX_WALL_PIECES`, :data:`MAX_ARC_STEPS` and
    :data:`MAX_WALL_VERTICES` (a finer mesh takes minutes; raise ``max_error`` instead)."""
    max_error = check_finite("max_error", max_error, minimum=MIN_MAX_ERROR)
    wall = float(shape.wall)
    if not wall >= MIN_WALL:
        raise InvalidParameterError(f"{who}: wall {wall!r} m is thinner than {MIN_WALL} m")
    if isinstance(shape, BoxShell):
        return 0, 0
    h = wall / 2
    rho_max = float(shape.points[:, 0].max()) + h
    if not math.isfinite(rho_max):
        raise InvalidParameterError(f"{who}: outer radius {rho_max!r} is not finite")
    sectors = max(8, _arc_steps(rho_max, max_error / 2, 2 * math.pi))
    arc_steps = max(2, _arc_steps(h, max_error / 2, math.pi))
    pieces = sectors * (len(shape.points) - 1)
    verts = pieces * 4 * (arc_steps + 1)
    for what, n, limit in (
        ("wall pieces", pieces, MAX_WALL_PIECES),
        ("chords on a rim arc", arc_steps, MAX_ARC_STEPS),
        ("mesh vertices", verts, MAX_WALL_VERTICES),
    ):
        if n > limit:
            raise InvalidParameterError(
                f"{who} at max_error={max_error!r} needs {n} {what} (limit {limit}); "
                "raise max_error or shrink the container"
            )
    return sectors, arc_steps


def _wall_pieces(shape: ContainerShape, max_error: object, who: str) -> list[np.ndarray]:
    sectors, arc_steps = _wall_plan(shape, max_error, who)
    if isinstance(shape, BoxShell):
        return _box_pieces(shape)
    h = shape.wall / 2
    pts = shape.points
    k = 2.0 / (1.0 + math.cos(math.pi / sectors))  # straddle the sector chords
    phi = np.linspace(0.0, 2 * math.pi, sectors + 1)
    pieces = []
    for a, b in itertools.pairwise(pts):
        poly = _stadium(a, b, h, arc_steps)
        rho, z = poly[:, 0] * k, poly[:, 1]
        for p0, p1 in itertools.pairwise(phi):
            v = [np.stack([rho * math.cos(p), rho * math.sin(p), z], axis=1) for p in (p0, p1)]
            pieces.append(np.unique(np.round(np.concatenate(v), 12), axis=0))
    return pieces


def _box_pieces(shape: BoxShell) -> list[np.ndarray]:
    hx, hy, w, d = shape.half_x, shape.half_y, shape.wall, shape.depth
    boxes = [  # (centre, half sizes): bottom, then +-x and +-y walls
        ((0, 0, w / 2), (hx + w, hy + w, w / 2)),
        ((hx + w / 2, 0, w + d / 2), (w / 2, hy + w, d / 2)),
        ((-hx - w / 2, 0, w + d / 2), (w / 2, hy + w, d / 2)),
        ((0, hy + w / 2, w + d / 2), (hx, w / 2, d / 2)),
        ((0, -hy - w / 2, w + d / 2), (hx, w / 2, d / 2)),
    ]
    corners = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)])
    return [np.asarray(c) + corners * np.asarray(s) for c, s in boxes]


def _is_number(v: object) -> bool:
    return isinstance(v, int | float) and not isinstance(v, bool)


def _build(name: str, entry: object, path: Path) -> Container:
    where = f"container.{name}"
    if not name:
        raise ProfileFileError(path, where, "a container needs a non-empty name")
    if not isinstance(entry, dict):
        raise ProfileFileError(path, where, f"must be a table, got {entry!r}")

    def key(k: str) -> object:
        if k not in entry:
            raise ProfileFileError(path, f"{where}.{k}", "missing")
        return entry[k]

    def number(k: str) -> float:
        v = key(k)
        if not _is_number(v) or not math.isfinite(v):
            raise ProfileFileError(path, f"{where}.{k}", f"must be a finite number, got {v!r}")
        return float(v)

    kind = key("kind")
    if not isinstance(kind, str) or kind not in KINDS:
        raise ProfileFileError(path, f"{where}.kind", f"{kind!r} not one of {list(KINDS)}")
    role = key("role")
    if not isinstance(role, str) or role not in ROLES:
        raise ProfileFileError(path, f"{where}.role", f"{role!r} not one of {ROLES}")
    unknown = set(entry) - set(_COMMON) - set(KINDS[kind])
    if unknown:
        raise ProfileFileError(path, where, f"unknown keys {sorted(unknown)}")
    args: dict[str, object] = {k: number(k) for k in KINDS[kind] if k != "points"}
    if args["wall"] < MIN_WALL:
        raise ProfileFileError(
            path, f"{where}.wall", f"must be >= {MIN_WALL} m, got {args['wall']!r}"
        )
    if kind == "profile":
        pts = key("points")
        if not isinstance(pts, list) or not all(
            isinstance(p, list) and len(p) == 2 and all(_is_number(x) for x in p) for p in pts
        ):
            raise ProfileFileError(
                path, f"{where}.points", f"must be a list of [rho, z] numbers, got {pts!r}"
            )
        args["points"] = pts
    try:
        if kind == "profile":
            shape = RevolvedShell(tuple(tuple(map(float, p)) for p in args["points"]), args["wall"])
        else:
            shape = {"cup": cup, "bowl": bowl, "bottle": bottle, "tray": tray}[kind](**args)
        size = (2.0 * _outer_radius_max(shape), shape.rim_height)
    except (TypeError, ValueError, ArithmeticError) as exc:
        raise ProfileFileError(path, where, str(exc)) from exc
    if not all(math.isfinite(x) and x <= MAX_SIZE for x in size):
        raise ProfileFileError(
            path,
            where,
            f"outer diameter {size[0]!r} m and rim height {size[1]!r} m must be <= {MAX_SIZE} m",
        )
    mass, grasp = number("mass"), number("grasp_height")
    if not mass > 0:
        raise ProfileFileError(path, f"{where}.mass", f"must be > 0, got {mass!r}")
    if not (0 <= grasp <= shape.rim_height):
        raise ProfileFileError(path, f"{where}.grasp_height", f"must be in [0, {shape.rim_height}]")
    rgba = key("rgba")
    if not (
        isinstance(rgba, list)
        and len(rgba) == 4
        and all(_is_number(c) and 0.0 <= c <= 1.0 for c in rgba)
    ):
        raise ProfileFileError(path, f"{where}.rgba", f"needs 4 numbers in [0, 1], got {rgba!r}")
    description = key("description")
    if not isinstance(description, str):
        raise ProfileFileError(
            path, f"{where}.description", f"must be a string, got {description!r}"
        )
    rgba = tuple(float(c) for c in rgba)
    return Container(name, role, kind, shape, mass, grasp, rgba, description)


def load_containers(path: str | Path | None = None) -> dict[str, Container]:
    """Read a container file (default: the shipped ``assets/containers.toml``).

    Every length is in m; walls must be at least :data:`MIN_WALL` thick, outer diameters and
    rim heights at most :data:`MAX_SIZE`, ``rgba`` 4 numbers in [0, 1].

    Raises:
        ProfileFileError: an unreadable file, invalid TOML, or a malformed entry, naming the
            file and key.
    """
    path = Path(path) if path is not None else DEFAULT_PATH
    data = read_toml(path)
    table = data.get("container")
    if not isinstance(table, dict) or not table:
        raise ProfileFileError(path, "container", "no [container.<name>] tables")
    return {name: _build(name, entry, path) for name, entry in table.items()}


@cache
def _shipped() -> dict[str, Container]:
    return load_containers()


def container_names(role: str | None = None) -> tuple[str, ...]:
    """Names of the shipped containers, optionally only those of one ``role``."""
    if role is not None and role not in ROLES:
        raise UnknownNameError("container role", role, ROLES)
    return tuple(n for n, c in _shipped().items() if role is None or c.role == role)


def get_container(name: str) -> Container:
    """The shipped container ``name``.

    Raises:
        UnknownNameError: ``name`` is not in ``containers.toml`` (lists the known ones).
    """
    try:
        return _shipped()[name]
    except (KeyError, TypeError):
        raise UnknownNameError("container", name, _shipped()) from None


def add_container_body(
    spec: mujoco.MjSpec,
    parent: mujoco.MjsBody,
    container: Container | str,
    *,
    name: str | None = None,
    pos: tuple[float, float, float] | np.ndarray = (0.0, 0.0, 0.0),
    quat: tuple[float, float, float, float] | np.ndarray = (1.0, 0.0, 0.0, 0.0),
    mocap: bool = False,
    max_error: float = DEFAULT_MAX_ERROR,
) -> mujoco.MjsBody:
    """Add ``container`` as a body (no joint) under ``parent`` in ``spec``.

    The body gets one convex mesh geom per wall piece (mass shared by volume, so the body's
    mass and inertia follow the wall), a ``<name>_mount`` site (see module docstring) and a
    ``<name>_rim`` site at the centre of the mouth.

    Args:
        spec: the spec to add meshes to.
        parent: body to attach to (``spec.worldbody`` for a free-standing or mocap container).
        container: a :class:`Container` or the name of a shipped one.
        name: body name (default the container's name); prefixes the mesh and site names.
        pos: body position in the parent frame, m.
        quat: body orientation in the parent frame (w, x, y, z).
        mocap: make it a mocap body (``parent`` must then be the world body).
        max_error: mesh accuracy, m (see :meth:`Container.wall_pieces`).

    Raises:
        UnknownNameError: ``container`` names no shipped container.
        InvalidParameterError: anything else malformed: ``pos`` not 3 finite numbers, ``quat``
            not 4 of non-zero norm, a ``max_error`` or mesh that :meth:`Container.wall_pieces`
            refuses, a name already in ``spec``, a mocap body under another body than the
            world. Nothing is added to ``spec`` then.
    """
    if isinstance(container, str):
        c = get_container(container)
    elif isinstance(container, Container):
        c = container
    else:
        raise InvalidParameterError(
            f"container must be a Container or a container name, got {container!r}"
        )
    if name is not None and not isinstance(name, str):
        raise InvalidParameterError(f"name must be a string, got {name!r}")
    name = name or c.name
    if mocap and parent != spec.worldbody:
        raise InvalidParameterError(f"mocap body {name!r}: parent must be spec.worldbody")
    pos_arr = check_array("pos", pos, (3,))
    quat_arr = check_quat("quat", quat)  # MuJoCo normalises it
    for taken, lookup in (
        (name, spec.body),
        (f"{name}_wall_0", spec.mesh),
        (f"{name}_wall_0", spec.geom),
        (f"{name}_mount", spec.site),
        (f"{name}_rim", spec.site),
    ):
        if lookup(taken) is not None:
            raise InvalidParameterError(f"name {name!r}: {taken!r} is already in the spec")
    pieces = _wall_pieces(c.shape, max_error, f"container {c.name!r}")
    volumes = np.array([ConvexHull(p).volume for p in pieces])
    body = parent.add_body(
        name=name, pos=pos_arr.tolist(), quat=quat_arr.tolist(), mocap=bool(mocap)
    )
    for i, (verts, vol) in enumerate(zip(pieces, volumes, strict=True)):
        mesh = spec.add_mesh(name=f"{name}_wall_{i}")
        mesh.uservert = verts.ravel().tolist()
        body.add_geom(
            name=f"{name}_wall_{i}",
            type=mujoco.mjtGeom.mjGEOM_MESH,
            meshname=mesh.name,
            mass=c.mass * vol / volumes.sum(),
            rgba=list(c.rgba),
            contype=CONTAINER_CONTYPE,
            conaffinity=CONTAINER_CONAFFINITY,
            group=2,
        )
    mpos, mquat = c.mount_pose()
    body.add_site(name=f"{name}_mount", pos=mpos.tolist(), quat=mquat.tolist(), size=[0.01] * 3)
    body.add_site(name=f"{name}_rim", pos=[0.0, 0.0, c.rim_height], size=[0.005] * 3)
    return body
