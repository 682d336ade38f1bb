"""Ready-made fluid scenes: a source cup tilted over a target cup on a force sensor.

Used by ``pourbench demo``, the physics tests and ``pourbench bench fluids``. The scene is a
small MJCF of its own (table plane, a kinematic mocap source cup, a target cup on a 6-axis
force/torque sensor) so the liquid core can be exercised without the robot models.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import mujoco
import numpy as np

from pourbench.errors import InvalidParameterError, check_finite
from pourbench.fluids.config import SolverConfig
from pourbench.fluids.coupling import MujocoCoupling
from pourbench.fluids.metrics import LiquidMetrics, liquid_metrics
from pourbench.fluids.params import LiquidProfile
from pourbench.fluids.solver import PBFSolver
from pourbench.geometry.shapes import RevolvedShell, cup

GRAVITY = 9.81

_MJCF = """
<mujoco model="two_cups">
  <option timestep="{dt}" gravity="0 0 -{g}"/>
  <worldbody>
    <geom name="table" type="plane" size="0.5 0.5 0.01" rgba="0.6 0.5 0.4 1"/>
    <body name="target" pos="{tx} 0 0">
      <geom name="target_base" type="cylinder" size="{tr} 0.002" pos="0 0 0.002" mass="0.1"
            contype="0" conaffinity="0"/>
      <site name="target_ft" pos="0 0 0"/>
    </body>
    <body name="source" mocap="true" pos="0 0 {sz}">
      <geom name="source_base" type="cylinder" size="{sr} 0.002" pos="0 0 0.002"
            contype="0" conaffinity="0"/>
    </body>
  </worldbody>
  <sensor>
    <force name="target_force" site="target_ft"/>
    <torque name="target_torque" site="target_ft"/>
  </sensor>
</mujoco>
"""


@dataclass
class PourScene:
    """A built two-cup scene; ``source``/``target`` are collider indices per world."""

    solver: PBFSolver
    coupling: MujocoCoupling
    model: mujoco.MjModel
    datas: list[mujoco.MjData]
    source_shape: RevolvedShell
    target_shape: RevolvedShell
    source: list[int]
    target: list[int]
    source_home: np.ndarray
    lip: np.ndarray
    tare_n: np.ndarray

    def set_tilt(self, theta: float | np.ndarray) -> None:
        """Tilt the source cup by ``theta`` (rad, per world or scalar) about its pouring lip."""
        th = np.broadcast_to(np.asarray(theta, float), (self.solver.num_worlds,))
        for d, a in zip(self.datas, th, strict=True):
            c, s = math.cos(a), math.sin(a)
            rot = np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])  # about +y: mouth toward +x
            d.mocap_pos[0] = self.lip + rot @ (self.source_home - self.lip)
            d.mocap_quat[0] = [math.cos(a / 2), 0.0, math.sin(a / 2), 0.0]

    def step(self, n: int = 1) -> None:
        self.coupling.step(n)

    def weight_g(self, world: int = 0) -> float:
        """Liquid weight on the target's force sensor (tared, no filtering), grams."""
        fz = self.datas[world].sensor("target_force").data[2]
        return float((fz - self.tare_n[world]) / GRAVITY * 1e3)

    def metrics(self, world: int = 0) -> LiquidMetrics:
        return liquid_metrics(self.solver, world, [self.source[world], self.target[world]])


def two_cup_scene(
    liquid: str | LiquidProfile | Sequence[str | LiquidProfile] = "water",
    mass_g: float = 200.0,
    num_worlds: int = 1,
    config: SolverConfig | None = None,
    target_g: float = 0.0,
) -> PourScene:
    """Build the scene; fill the source cup with ``mass_g`` (and the target with ``target_g``)
    grams of ``liquid`` in every world (or of ``liquid[w]`` in world ``w``).

    The source cup's pouring lip sits 1 cm above the target's rim and 4 cm inside its mouth,
    so tilting about the lip pours into the target.
    """
    check_finite("mass_g", mass_g, minimum=0.0)
    check_finite("target_g", target_g, minimum=0.0)
    config = config or SolverConfig()
    source = cup(0.04, 0.08)
    target = cup(0.10, 0.06)  # the thesis' receiving tray has a 10 cm radius
    lip_x = source.outer_radius
    tx = lip_x + target.mouth_radius - 0.04
    sz = target.rim_height + 0.01
    xml = _MJCF.format(
        dt=repr(config.dt), g=GRAVITY, tx=tx, tr=target.outer_radius, sz=sz, sr=source.outer_radius
    )
    model = mujoco.MjModel.from_xml_string(xml)
    datas = [mujoco.MjData(model) for _ in range(num_worlds)]
    for d in datas:
        mujoco.mj_forward(model, d)
    tare = np.array([d.sensor("target_force").data[2] for d in datas])
    solver = PBFSolver(num_worlds, config)
    coupling = MujocoCoupling(solver, model, datas)
    coupling.add_geoms(["table"])
    src = coupling.add_container("source", source)
    tgt = coupling.add_container("target", target)
    liquids = [liquid] * num_worlds if isinstance(liquid, str | LiquidProfile) else list(liquid)
    if len(liquids) != num_worlds:
        raise InvalidParameterError(f"{len(liquids)} liquids given for {num_worlds} worlds")
    for w, liq in enumerate(liquids):
        solver.set_liquid(w, liq)
        if mass_g > 0:
            solver.fill(w, src[w], mass_g)
        if target_g > 0:
            solver.fill(w, tgt[w], target_g)
    home = np.array([0.0, 0.0, sz])
    lip = np.array([lip_x, 0.0, sz + source.rim_height])
    return PourScene(solver, coupling, model, datas, source, target, src, tgt, home, lip, tare)


def tilt_schedule(t: float, rate_deg_s: float = 45.0, max_deg: float = 135.0) -> float:
    """The test and demo tilt: constant rate up to ``max_deg``, then hold (rad)."""
    return math.radians(min(rate_deg_s * t, max_deg))
