"""The liquid library: every thesis profile loads with the thesis' numbers; bad files are named."""

from __future__ import annotations

import math

import pytest

from pourbench.errors import ProfileFileError, UnknownNameError
from pourbench.fluids import liquid_names, liquid_profile, load_liquids

TABLE_6_2 = {  # adhesion, cohesion, surface tension, viscosity
    "Water": (1e-4, 1e-3, 5e-3, 0.01),
    "Ink": (1e-4, 2.5e-3, 7.5e-3, 0.05),
    "Oil": (1e-3, 1e-3, 1e-4, 6.5),
    "Glycerine": (5e-3, 1e-3, 1e-4, 50.0),
    "Honey": (0.025, 1e-3, 1e-4, 65.0),
    "Ketchup": (0.1, 1e-3, 1e-5, 80.0),
}
TABLE_3_3_DENSITY = {  # g/ml
    "apple juice": 0.98,
    "washing soap": 1.06,
    "handgel": 0.81,
    "honey": 1.5,
    "rapeseed oil": 0.92,
    "balsamico": 1.05,
    "joghurt": 1.08,
    "hand soap": 1.0,
    "shampoo": 1.0,
    "milk": 0.99,
}
TABLE_3_4_VISCOSITY = {  # cP
    "water": 0.87,
    "apple": 1.15,
    "rapeseed oil": 1.39,
    "handgel": 4.85,
    "dish soap": 14.99,
    "hand soap": 37.4,
    "honey": 302.35,
}


@pytest.mark.parametrize("name", sorted(TABLE_6_2))
def test_table_6_2_profiles(name: str) -> None:
    p = liquid_profile(name.upper())
    assert (p.adhesion, p.cohesion, p.surface_tension, p.viscosity) == TABLE_6_2[name]


def test_table_3_5_columns() -> None:
    honey = liquid_profile("RRS Honey")
    flex = honey.to_flex()
    assert flex["solidRest"] == 0.05 and flex["fluidRest"] == 0.16
    assert flex["adhesion"] == 0.003 and flex["dissipation"] == 4 and flex["damping"] == 2
    assert flex["buoyancy"] == 3 and flex["viscosity"] == 1
    assert liquid_profile("hand-gel").buoyancy == 2.2
    assert liquid_profile("Ketchup") is not liquid_profile("rrs ketchup")
    assert liquid_profile("rrs ketchup").surface_tension == 0.01


@pytest.mark.parametrize("name,rho", sorted(TABLE_3_3_DENSITY.items()))
def test_measured_density(name: str, rho: float) -> None:
    assert math.isclose(liquid_profile(name).density, rho * 1000.0)


@pytest.mark.parametrize("name,mu", sorted(TABLE_3_4_VISCOSITY.items()))
def test_measured_viscosity(name: str, mu: float) -> None:
    assert liquid_profile(name).viscosity_cp == mu


def test_table_6_4_liquids_present() -> None:
    names = ["water", "milk", "cola", "orange juice", "rapeseed oil", "dish soap", "honey"]
    found = {liquid_profile(n).name for n in names}
    assert found == {"Water", "Milk", "Cola", "Orange Juice", "Rapeseed Oil", "Dish Soap", "Honey"}


def test_derived_profile_takes_base_flex_but_not_base_measurements() -> None:
    apple, water = liquid_profile("apple juice"), liquid_profile("water")
    assert apple.viscosity == water.viscosity and apple.adhesion == water.adhesion
    assert apple.density == 980.0 and apple.viscosity_cp == 1.15
    assert liquid_profile("balsamico").viscosity_cp is None


def test_names_are_unique_and_resolvable() -> None:
    names = liquid_names()
    assert len(names) == len(set(names)) >= 20
    for n in names:
        assert liquid_profile(n).name == n


def test_unknown_name_lists_known() -> None:
    with pytest.raises(UnknownNameError) as err:
        liquid_profile("mercury")
    assert "mercury" in str(err.value) and "Water" in str(err.value)
    assert isinstance(err.value, ValueError)


def test_bad_values_name_the_parameter() -> None:
    water = liquid_profile("water")
    with pytest.raises(ValueError, match="viscosity"):
        water.replace(viscosity=float("nan"))
    with pytest.raises(ValueError, match="cohesion"):
        water.replace(cohesion=-1.0)
    assert water.replace(viscosity=2.0).viscosity == 2.0


@pytest.mark.parametrize(
    "body,key",
    [
        ("[profile.x]\nname='X'\nviscosity='thick'\n", "profile.x.viscosity"),
        ("[profile.x]\nname='X'\nviscositee=1.0\n", "profile.x.viscositee"),
        ("[profile.x]\nbase='nope'\n", "profile.x.base"),
        ("[profile.x]\ndensity=-3.0\n", "profile.x"),
        ("[profile.x\n", "<file>"),
        ("[profile.x]\naliases='xx'\n", "profile.x.aliases"),
        ("[profile.x]\nname=5\n", "profile.x.name"),
        ("[profile.x]\nbase=['y']\n[profile.y]\n", "profile.x.base"),
        ("[profile.x]\nname='Same'\n[profile.y]\nname='same'\n", "profile.y"),
        ("\xff", "<file>"),
    ],
)
def test_malformed_file_names_file_and_key(tmp_path, body: str, key: str) -> None:
    good = (
        "[defaults]\n" + "\n".join(f"{k} = 1.0" for k in liquid_profile("water").to_flex()) + "\n"
    )
    path = tmp_path / "bad.toml"
    text = (good + body).encode("utf-8")
    path.write_bytes(text.replace("\xff".encode(), b"\xff"))  # "\xff": a byte not UTF-8
    with pytest.raises(ProfileFileError) as err:
        load_liquids(path)
    assert str(path) in str(err.value) and key in str(err.value)


def test_a_missing_liquids_file_is_named(tmp_path) -> None:
    with pytest.raises(ProfileFileError, match=r"nope\.toml: key .<file>.: cannot read"):
        load_liquids(tmp_path / "nope.toml")
