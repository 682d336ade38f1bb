"""The container family: ``assets/containers.toml`` -> fluid colliders and MuJoCo bodies.

Each entry of the TOML file becomes a :class:`Container` whose ``shape`` is the fluid solver's
signed-distance collider (a :mod:`pourbench.fluids.shapes` object). :func:`add_container_body`
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
import tomllib
from dataclasses import dataclass
from functools import cache
from importlib import resources
from pathlib import Path

import mujoco
import numpy as np
from scipy.spatial import ConvexHull

from pourbench.errors import ProfileFileError, UnknownNameError
from pourbench.fluids.shapes import BoxShell, ContainerShape, RevolvedShell, bottle, bowl, cup, tray

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
        """Convex pieces whose union is the wall, each an (n, 3) vertex array in m.

        Args:
            max_error: bound on the distance between the pieces' surface and the SDF's zero
                level set, m.
        """
        return wall_pieces(self.shape, max_error)


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


def wall_pieces(shape: ContainerShape, max_error: float = DEFAULT_MAX_ERROR) -> list[np.ndarray]:
    """Convex pieces (each an (n, 3) vertex array, m) whose union is ``shape``'s wall."""
    if isinstance(shape, BoxShell):
        return _box_pieces(shape)
    h = shape.wall / 2
    pts = shape.points
    rho_max = float(pts[:, 0].max()) + h
    sectors = max(8, _arc_steps(rho_max, max_error / 2, 2 * math.pi))
    arc_steps = max(2, _arc_steps(h, max_error / 2, math.pi))
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


def _build(name: str, entry: dict, path: Path) -> Container:
    def key(k: str) -> object:
        if k not in entry:
            raise ProfileFileError(path, f"container.{name}.{k}", "missing")
        return entry[k]

    kind = key("kind")
    if kind not in KINDS:
        raise ProfileFileError(path, f"container.{name}.kind", f"{kind!r} not one of {list(KINDS)}")
    role = key("role")
    if role not in ROLES:
        raise ProfileFileError(path, f"container.{name}.role", f"{role!r} not one of {ROLES}")
    unknown = set(entry) - set(_COMMON) - set(KINDS[kind])
    if unknown:
        raise ProfileFileError(path, f"container.{name}", f"unknown keys {sorted(unknown)}")
    args = {k: key(k) for k in KINDS[kind]}
    try:
        if kind == "profile":
            shape = RevolvedShell(tuple(tuple(map(float, p)) for p in args["points"]), args["wall"])
        else:
            shape = {"cup": cup, "bowl": bowl, "bottle": bottle, "tray": tray}[kind](**args)
    except (TypeError, ValueError) as exc:
        raise ProfileFileError(path, f"container.{name}", str(exc)) from exc
    mass, grasp = float(key("mass")), float(key("grasp_height"))
    if not (mass > 0 and math.isfinite(mass)):
        raise ProfileFileError(path, f"container.{name}.mass", f"must be > 0, got {mass!r}")
    if not (0 <= grasp <= shape.rim_height):
        raise ProfileFileError(
            path, f"container.{name}.grasp_height", f"must be in [0, {shape.rim_height}]"
        )
    rgba = tuple(float(c) for c in key("rgba"))
    if len(rgba) != 4:
        raise ProfileFileError(path, f"container.{name}.rgba", "needs 4 numbers")
    return Container(name, role, kind, shape, mass, grasp, rgba, str(key("description")))


def load_containers(path: str | Path | None = None) -> dict[str, Container]:
    """Read a container file (default: the shipped ``assets/containers.toml``).

    Raises:
        ProfileFileError: a malformed entry, naming the file and key.
    """
    path = Path(path) if path is not None else DEFAULT_PATH
    with open(path, "rb") as f:
        data = tomllib.load(f)
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
        max_error: mesh accuracy, m (see :func:`wall_pieces`).

    Returns:
        The new body.
    """
    c = get_container(container) if isinstance(container, str) else container
    name = name or c.name
    body = parent.add_body(name=name, pos=list(pos), quat=list(quat), mocap=mocap)
    pieces = c.wall_pieces(max_error)
    volumes = np.array([ConvexHull(p).volume for p in pieces])
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
