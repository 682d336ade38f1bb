"""Liquid profiles: FleX-named parameters loaded from ``assets/liquids.toml``.

The TOML file is the single source of the thesis' liquids (SPEC §1). Names are matched
case-insensitively, with spaces, hyphens and underscores treated alike.
"""

from __future__ import annotations

import dataclasses
import math
import numbers
from dataclasses import dataclass
from functools import cache
from importlib import resources
from pathlib import Path

from pourbench.errors import InvalidParameterError, ProfileFileError, UnknownNameError, read_toml
from pourbench.fluids.rheology import HerschelBulkley

# FleX parameter name -> LiquidProfile attribute.
FLEX_NAMES: dict[str, str] = {
    "solidRest": "solid_rest",
    "fluidRest": "fluid_rest",
    "cohesion": "cohesion",
    "surfaceTension": "surface_tension",
    "viscosity": "viscosity",
    "vorticityConfinement": "vorticity_confinement",
    "adhesion": "adhesion",
    "staticFriction": "static_friction",
    "dynamicFriction": "dynamic_friction",
    "particleFriction": "particle_friction",
    "dissipation": "dissipation",
    "damping": "damping",
    "buoyancy": "buoyancy",
    "density": "density",
}
_RHEOLOGY = {"yield_stress_pa", "consistency_pa_sn", "flow_index"}
_OPTIONAL = {"viscosity_cp", "viscosity_pa_s", "marble_speed", "marble_viscosity_cp"} | _RHEOLOGY
_TEXT = {"name", "source", "viscosity_source"}
_META = {"base", "aliases"} | _TEXT


@dataclass(frozen=True)
class LiquidProfile:
    """One liquid: FleX parameters (dimensionless, FleX's meaning) plus physical density.

    Attributes:
        name: the thesis' name ("Water", "Dish Soap", ...).
        density: physical rest density, kg/m^3 (sets the particle mass).
        viscosity: FleX XSPH viscosity coefficient (Table 6.2: 0.01 water ... 80 ketchup).
        cohesion, surface_tension, adhesion: FleX coefficients.
        static_friction, dynamic_friction, particle_friction: FleX friction coefficients.
        dissipation: velocity damping on contact with shapes; damping: global drag, 1/s.
        vorticity_confinement: FleX vorticity confinement strength.
        buoyancy: FleX gravity scale for fluid particles (kept for provenance; 1 = full gravity).
        solid_rest, fluid_rest: the thesis' Unity-FleX rest values (provenance only).
        viscosity_pa_s: the liquid's dynamic viscosity, Pa·s, that the solver applies by an
            implicit solve (:mod:`pourbench.fluids.viscosity`); None: none, and the FleX
            ``viscosity`` drives XSPH smoothing as in FleX (docs/viscosity.md).
        viscosity_cp: the same dynamic viscosity in centipoise, an alternative input: given
            alone it sets ``viscosity_pa_s`` (cP / 1000); given with it, the two must agree.
        viscosity_source: where ``viscosity_pa_s`` comes from (a publication or a derivation).
        yield_stress_pa, consistency_pa_sn, flow_index: a Herschel–Bulkley law τ = τ_y + K γ̇ⁿ
            (Pa, Pa·sⁿ, dimensionless; :mod:`pourbench.fluids.rheology`) that the implicit
            solve applies instead of the constant ``viscosity_pa_s``. ``consistency_pa_sn``
            turns it on; the yield stress defaults to 0 and the index to 1. ``viscosity_pa_s``
            stays the liquid's apparent viscosity at a pour's shear rate: what the pouring
            tasks observe and the scale the solve is set up with.
        marble_speed: falling-ball speed (m/s) in Table 3.4, if measured.
        marble_viscosity_cp: Table 3.4's viscosity (cP) as the thesis computed it from that
            speed by Stokes' law without a wall or inertia correction (provenance only;
            :mod:`pourbench.fluids.falling_ball` redoes it with both).
        source: where each number comes from.
    """

    name: str
    density: float
    viscosity: float
    cohesion: float
    surface_tension: float
    adhesion: float
    static_friction: float
    dynamic_friction: float
    particle_friction: float
    dissipation: float
    damping: float
    vorticity_confinement: float
    buoyancy: float
    solid_rest: float
    fluid_rest: float
    viscosity_pa_s: float | None = None
    viscosity_cp: float | None = None
    marble_speed: float | None = None
    marble_viscosity_cp: float | None = None
    yield_stress_pa: float | None = None
    consistency_pa_sn: float | None = None
    flow_index: float | None = None
    source: str = ""
    viscosity_source: str = ""

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):
            if f.name in _TEXT:
                if not isinstance(getattr(self, f.name), str):
                    raise InvalidParameterError(
                        f"liquid {f.name} must be a string, got {getattr(self, f.name)!r}"
                    )
                continue
            v = getattr(self, f.name)
            if v is None and f.name in _OPTIONAL:
                continue
            what = f"liquid {self.name!r}: {f.name}"
            if isinstance(v, bool) or not isinstance(v, numbers.Real):
                raise InvalidParameterError(f"{what} must be a number, got {v!r}")
            if math.isnan(v) or math.isinf(v):
                raise InvalidParameterError(f"{what} must be finite, got {v!r}")
            if v < 0 or (f.name == "density" and v == 0):
                raise InvalidParameterError(f"{what} must be positive, got {v!r}")
        cp, pa_s = self.viscosity_cp, self.viscosity_pa_s
        if cp is not None and pa_s is not None and not math.isclose(cp * 1e-3, pa_s, rel_tol=1e-6):
            raise InvalidParameterError(
                f"liquid {self.name!r}: viscosity_cp {cp!r} (cP) and viscosity_pa_s {pa_s!r} "
                "(Pa·s) disagree; give one, or both equal"
            )
        if cp is not None and pa_s is None:
            object.__setattr__(self, "viscosity_pa_s", cp * 1e-3)
        given = sorted(k for k in _RHEOLOGY if getattr(self, k) is not None)
        if given and self.consistency_pa_sn is None:
            raise InvalidParameterError(
                f"liquid {self.name!r}: {given} need consistency_pa_sn (a Herschel–Bulkley "
                "law is τ = yield_stress_pa + consistency_pa_sn × rate ** flow_index)"
            )
        if given and self.viscosity_pa_s is None:
            raise InvalidParameterError(
                f"liquid {self.name!r}: a Herschel–Bulkley law needs viscosity_pa_s too, the "
                "apparent viscosity at a pour's shear rate"
            )
        if given:
            self.rheology()  # the law's own checks

    def rheology(self) -> HerschelBulkley | None:
        """The liquid's shear law: its Herschel–Bulkley law, a Newtonian one of
        ``viscosity_pa_s`` (τ_y 0, n 1), or None without a physical viscosity."""
        if self.consistency_pa_sn is not None:
            return HerschelBulkley(
                self.yield_stress_pa or 0.0,
                self.consistency_pa_sn,
                1.0 if self.flow_index is None else self.flow_index,
            )
        if self.viscosity_pa_s:
            return HerschelBulkley(0.0, self.viscosity_pa_s, 1.0)
        return None

    def replace(self, **changes: float) -> LiquidProfile:
        """Copy with some attributes (snake_case or FleX names) changed; values are validated."""
        mapped = {FLEX_NAMES.get(k, k): v for k, v in changes.items()}
        known = {f.name for f in dataclasses.fields(self)}
        unknown = sorted(set(mapped) - known)
        if unknown:
            raise InvalidParameterError(
                f"unknown liquid parameter {unknown[0]!r}; known: {sorted(FLEX_NAMES)} or "
                f"{sorted(known)}"
            )
        return dataclasses.replace(self, **mapped)

    def to_flex(self) -> dict[str, float]:
        """The FleX-named parameters as a dict."""
        return {flex: getattr(self, attr) for flex, attr in FLEX_NAMES.items()}


def _norm(name: str) -> str:
    return " ".join(name.lower().replace("-", " ").replace("_", " ").split())


def load_liquids(path: str | Path | None = None) -> dict[str, LiquidProfile]:
    """Load every profile of a liquids TOML file, keyed by normalised name and alias.

    Raises:
        ProfileFileError: the file is not valid TOML, or an entry has a missing, unknown, or
            non-numeric key; the message names the file and key.
    """
    if path is None:  # the shipped file
        path = str(resources.files("pourbench") / "assets" / "liquids.toml")
    path = Path(path)
    doc = read_toml(path)
    defaults = doc.get("defaults", {})
    if not isinstance(defaults, dict):
        raise ProfileFileError(path, "defaults", "must be a table")
    raw = doc.get("profile")
    if not isinstance(raw, dict) or not raw:
        raise ProfileFileError(path, "profile", "no [profile.<name>] tables")
    resolved: dict[str, dict] = {}

    def resolve(key: str, chain: tuple[str, ...] = ()) -> dict:
        if key in resolved:
            return resolved[key]
        if key not in raw:
            raise ProfileFileError(path, f"profile.{chain[-1]}.base", f"unknown base {key!r}")
        if key in chain:
            raise ProfileFileError(path, f"profile.{key}.base", "circular base")
        entry = raw[key]
        if not isinstance(entry, dict):
            raise ProfileFileError(path, f"profile.{key}", "must be a table")
        base = entry.get("base")
        if base is not None and not isinstance(base, str):
            raise ProfileFileError(path, f"profile.{key}.base", f"must be a name, got {base!r}")
        merged = dict(defaults) if base is None else dict(resolve(base, (*chain, key)))
        if base is not None:  # measurements belong to the base liquid, not to this one
            for k in _OPTIONAL | {"aliases", "viscosity_source"}:
                merged.pop(k, None)
        merged.update(entry)
        resolved[key] = merged
        return merged

    out: dict[str, LiquidProfile] = {}
    for key in raw:
        fields = resolve(key)
        kwargs: dict[str, object] = {}
        for k, v in fields.items():
            if k in _META:
                continue
            attr = FLEX_NAMES.get(k, k if k in _OPTIONAL else None)
            if attr is None:
                raise ProfileFileError(path, f"profile.{key}.{k}", "unknown parameter")
            if isinstance(v, bool) or not isinstance(v, int | float):
                raise ProfileFileError(path, f"profile.{key}.{k}", f"must be a number, got {v!r}")
            kwargs[attr] = float(v)
        missing = [flex for flex, attr in FLEX_NAMES.items() if attr not in kwargs]
        if missing:
            raise ProfileFileError(path, f"profile.{key}.{missing[0]}", "missing parameter")
        name = fields.get("name", key)
        aliases = fields.get("aliases", [])
        if not isinstance(name, str):
            raise ProfileFileError(path, f"profile.{key}.name", f"must be a string, got {name!r}")
        if not isinstance(aliases, list) or not all(isinstance(a, str) for a in aliases):
            raise ProfileFileError(
                path, f"profile.{key}.aliases", f"must be a list of strings, got {aliases!r}"
            )
        try:
            text = {k: fields[k] for k in ("source", "viscosity_source") if k in fields}
            profile = LiquidProfile(name=name, **text, **kwargs)
        except InvalidParameterError as exc:
            raise ProfileFileError(path, f"profile.{key}", str(exc)) from exc
        for alias in (key, name, *aliases):
            other = out.get(_norm(alias))
            if other is not None and other is not profile:
                raise ProfileFileError(
                    path, f"profile.{key}", f"{alias!r} already names liquid {other.name!r}"
                )
            out[_norm(alias)] = profile
    return out


@cache
def _library() -> dict[str, LiquidProfile]:
    return load_liquids()


def liquid_names() -> list[str]:
    """The thesis' names of every shipped liquid profile, in file order."""
    seen: dict[str, None] = {}
    for p in _library().values():
        seen.setdefault(p.name, None)
    return list(seen)


def liquid_profile(name: str | LiquidProfile) -> LiquidProfile:
    """Look a profile up by name (case-insensitive; aliases allowed). Profiles pass through.

    Raises:
        UnknownNameError: the name is not in the library; the message lists the known names.
    """
    if isinstance(name, LiquidProfile):
        return name
    try:
        return _library()[_norm(str(name))]
    except KeyError:
        raise UnknownNameError("liquid", name, liquid_names()) from None
