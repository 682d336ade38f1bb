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
def test_table_3_4_viscosity_is_kept_as_provenance(name: str, mu: float) -> None:
    assert liquid_profile(name).marble_viscosity_cp == mu


def test_every_profile_has_a_physical_viscosity_with_its_source() -> None:
    for name in liquid_names():
        p = liquid_profile(name)
        assert p.viscosity_pa_s is not None and p.viscosity_pa_s > 0, name
        assert len(p.viscosity_source) > 20, name


PUBLISHED_PA_S = {  # the real liquids' dynamic viscosity at 20 °C, and the range it may take
    "water": (0.001, 0.0011),  # IAPWS: 1.002 mPa·s
    "glycerine": (1.40, 1.42),  # Segur & Oberstar: 1.412
    "honey": (5.0, 20.0),  # honeys of 17–18 % moisture
    "milk": (0.0018, 0.0022),
    "oil": (0.05, 0.08),
    "cola": (0.0012, 0.0016),
    "orange juice": (0.0012, 0.003),
}


@pytest.mark.parametrize("name", sorted(PUBLISHED_PA_S))
def test_published_viscosities(name: str) -> None:
    lo, hi = PUBLISHED_PA_S[name]
    assert lo <= liquid_profile(name).viscosity_pa_s <= hi


def test_viscosity_order_of_table_6_2_follows_the_real_liquids() -> None:
    mu = [liquid_profile(n).viscosity_pa_s for n in TABLE_6_2]
    assert mu == sorted(mu) and len(set(mu)) == len(mu)


def test_table_6_4_liquids_present() -> None:
    names = ["water", "milk", "cola", "orange juice", "rapeseed oil", "dish soap", "honey"]
    found = {liquid_profile(n).name for n in names}
    assert found == {"Water", "Milk", "Cola", "Orange Juice", "Rapeseed Oil", "Dish Soap", "Honey"}


def test_derived_profile_takes_base_flex_but_not_base_measurements() -> None:
    apple, water = liquid_profile("apple juice"), liquid_profile("water")
    assert apple.viscosity == water.viscosity and apple.adhesion == water.adhesion
    assert apple.density == 980.0 and apple.marble_viscosity_cp == 1.15
    assert apple.viscosity_pa_s != water.viscosity_pa_s
    assert apple.viscosity_source != water.viscosity_source
    assert liquid_profile("balsamico").marble_viscosity_cp is None


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
        ("[profile.x]\nviscosity_pa_s=1.0\nyield_stress_pa=5.0\n", "profile.x"),
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


def test_a_herschel_bulkley_profile_loads_from_the_file(tmp_path) -> None:
    """The law's three numbers load as written, and the profile's rheology is that law."""
    good = "[defaults]\n" + "\n".join(f"{k} = 1.0" for k in liquid_profile("water").to_flex())
    path = tmp_path / "paste.toml"
    path.write_text(
        good + "\n[profile.paste]\nviscosity_pa_s = 20.0\nyield_stress_pa = 15.0\n"
        "consistency_pa_sn = 8.0\nflow_index = 0.3\n"
    )
    paste = load_liquids(path)["paste"]
    assert (paste.yield_stress_pa, paste.consistency_pa_sn, paste.flow_index) == (15.0, 8.0, 0.3)
    assert paste.rheology().stress(1.0) == pytest.approx(23.0)
