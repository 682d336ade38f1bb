"""Pouring-task pieces on constructed situations: Algorithm 4's action handler, Algorithm 5's
reward, the weight filter and the curriculum file (no liquid simulation)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import signal

from pourbench.envs.action_handler import ActionLimits, as_actions, handle_actions
from pourbench.envs.core import PourConfig
from pourbench.envs.curriculum import lesson_at, load_curriculum
from pourbench.envs.observation import GRAVITY, WeightFilter
from pourbench.envs.reward import ErrorHistory, RewardConfig, extrinsic_reward
from pourbench.errors import InvalidParameterError, UnknownNameError

LIM = ActionLimits()
DT = 0.1
T = np.zeros((1, 3))  # receiving container's base point
HALF = np.array([0.05])
H = 0.034  # receiving container height


def _handle(action, base, weight_g, target_g=100.0, tilt=0.5, mode="thesis"):
    return handle_actions(
        np.array([action], float),
        np.array([base], float),
        np.array([tilt]),
        T,
        HALF,
        H,
        np.array([weight_g]),
        np.array([target_g]),
        2.0,
        DT,
        LIM,
        mode,
    )


ABOVE = (0.01, -0.02, 0.12)


def test_below_target_only_forward_rotation() -> None:
    base, tilt, above = _handle((1.0, 1.0), ABOVE, weight_g=50.0)
    assert above[0]
    assert tilt[0] == pytest.approx(0.5 + LIM.max_rate * DT)
    np.testing.assert_array_equal(base[0], ABOVE)  # above: no translation
    _, tilt, _ = _handle((-1.0, 0.0), ABOVE, weight_g=50.0)
    assert tilt[0] == pytest.approx(0.5)  # backward refused below target − tolerance


def test_above_target_only_backward_rotation() -> None:
    _, tilt, _ = _handle((1.0, 0.0), ABOVE, weight_g=99.0)  # within the 2 g tolerance
    assert tilt[0] == pytest.approx(0.5)
    _, tilt, _ = _handle((-0.5, 0.0), ABOVE, weight_g=120.0)
    assert tilt[0] == pytest.approx(0.5 - 0.5 * LIM.max_rate * DT)


def test_translation_with_height_clearance_rule() -> None:
    low = (-0.3, 0.1, 0.05)  # below 2 × 0.034 + 0.05 = 0.118 m above the receiver
    base, tilt, above = _handle((1.0, 1.0), low, weight_g=0.0, tilt=0.0)
    assert not above[0] and tilt[0] == 0.0  # not above: no rotation
    step = base[0] - low
    assert step[2] == 0.0  # horizontal only
    assert np.linalg.norm(step) == pytest.approx(LIM.max_speed * DT)
    d = np.array([0.3, -0.1])
    np.testing.assert_allclose(step[:2] / np.linalg.norm(step), d / np.linalg.norm(d))
    high = (-0.3, 0.1, 0.3)
    base, _, _ = _handle((0.0, 1.0), high, weight_g=0.0, tilt=0.0)
    step = base[0] - high
    np.testing.assert_allclose(step / np.linalg.norm(step), -np.array(high) / np.linalg.norm(high))
    base, _, _ = _handle((0.0, -1.0), high, weight_g=0.0, tilt=0.0)  # r < 0 moves away
    assert np.linalg.norm(base[0]) > np.linalg.norm(high)


def test_translation_never_passes_the_axis() -> None:
    near = (-0.06, 0.0, 0.05)  # 1 cm outside the "above" square, step is 1.5 cm
    base, _, _ = _handle((0.0, 1.0), near, weight_g=0.0, tilt=0.0)
    assert base[0][0] <= 0.0 and base[0][0] > -0.06


def test_free_mode_applies_both_velocities() -> None:
    base, tilt, _ = _handle((-1.0, 1.0), ABOVE, weight_g=0.0, mode="free")
    assert tilt[0] == pytest.approx(0.5 - LIM.max_rate * DT)  # backward below target
    assert np.linalg.norm(base[0]) < np.linalg.norm(ABOVE)  # moves toward the receiver


def test_tilt_bounds_and_bad_actions() -> None:
    _, tilt, _ = _handle((1.0, 0.0), ABOVE, 0.0, tilt=LIM.max_tilt)
    assert tilt[0] == LIM.max_tilt
    with pytest.raises(InvalidParameterError, match="actions must be finite"):
        as_actions((np.nan, 0.0))
    with pytest.raises(UnknownNameError, match="unknown action_mode 'teleport'"):
        PourConfig(action_mode="teleport")


def _reward(
    pouring=False,
    collided=False,
    finished=False,
    err=0.0,
    avg=0.0,
    max_steps=200,
    per_g=0.0,
    timed_out=False,
):
    return extrinsic_reward(
        np.array([pouring]),
        np.array([collided]),
        np.array([finished]),
        np.array([err]),
        np.array([avg]),
        max_steps,
        RewardConfig(final_error_per_g=per_g),
        np.array([timed_out]),
    )[0]


def test_algorithm5_terms() -> None:
    assert _reward(pouring=True) == pytest.approx(-1 / 200)  # below target: step penalty
    assert _reward(pouring=False) == 0.0  # target reached, not yet finished
    assert _reward(pouring=True, collided=True, err=0.0) == pytest.approx(-1 - 1 / 200)
    assert _reward(collided=True, finished=True, err=0.0) == -1.0  # collision: no bonus
    assert _reward(finished=True, err=5.0, avg=15.0) == 2.0  # both bonuses
    assert _reward(finished=True, err=10.0, avg=20.0) == 2.0  # bounds are inclusive
    assert _reward(finished=True, err=15.0, avg=15.0) == 1.0  # only the average bonus
    assert _reward(finished=True, err=5.0, avg=25.0) == 1.0  # only the episode bonus
    assert _reward(finished=True, err=30.0, avg=30.0) == 0.0


def test_the_denser_option_counts_every_gram_of_the_final_error() -> None:
    assert _reward(finished=True, err=5.0, avg=15.0, per_g=0.02) == pytest.approx(2.0 - 0.1)
    assert _reward(finished=True, err=30.0, avg=30.0, per_g=0.02) == pytest.approx(-0.6)
    assert _reward(pouring=True, err=80.0, per_g=0.02) == pytest.approx(-1 / 200)  # not yet
    assert _reward(collided=True, finished=True, err=80.0, per_g=0.02) == -1.0  # collision
    # the step limit charges it too: never finishing does not escape it
    assert _reward(timed_out=True, err=80.0, per_g=0.02) == pytest.approx(-1.6)
    assert _reward(timed_out=True, err=80.0) == 0.0  # Algorithm 5 alone: nothing
    with pytest.raises(ValueError, match="final_error_per_g must be >= 0"):
        RewardConfig(final_error_per_g=-0.1)


def test_the_progress_option_pays_the_error_change_of_the_step() -> None:
    def reward(before: float, after: float, **flags: bool) -> float:
        kw = {"pouring": False, "collided": False, "finished": False, **flags}
        return extrinsic_reward(
            *(np.array([kw[k]]) for k in ("pouring", "collided", "finished")),
            np.array([after]),
            np.array([15.0]),  # running average error, g
            200,
            RewardConfig(progress_per_g=0.05),
            np.array([False]),
            previous_error_g=np.array([before]),
        )[0]

    assert reward(80.0, 70.0, pouring=True) == pytest.approx(-1 / 200 + 0.5)  # 10 g closer
    assert reward(5.0, 25.0) == pytest.approx(-1.0)  # 20 g past the target
    assert reward(4.0, 3.0, finished=True) == pytest.approx(2.0 + 0.05)  # both bonuses too
    with pytest.raises(ValueError, match="needs the error before the step"):
        extrinsic_reward(
            *(np.array([False]) for _ in range(3)),
            np.array([1.0]),
            np.array([1.0]),
            200,
            RewardConfig(progress_per_g=0.05),
        )


def test_error_history_window() -> None:
    h = ErrorHistory(2, window=3)
    np.testing.assert_array_equal(h.average(), [0.0, 0.0])
    for e in (30.0, 3.0, 6.0, 9.0):
        h.add(0, e)
    np.testing.assert_allclose(h.average(), [6.0, 0.0])  # the last 3 only, world 1 untouched


def test_weight_filter_step_response_and_delay() -> None:
    f = WeightFilter(2, noise_n=0.0)
    f.reset(0, 5.0)  # tared at 5 N
    f.reset(1, 5.0)
    load = 5.0 + 0.1 * GRAVITY  # 100 g on the scale
    values = []
    for _ in range(500):  # 5 s at 100 Hz
        f.sample(np.array([0]), np.array([load]), np.zeros(1))
        values.append(f.value_g[0])
    # the analog 2nd-order Butterworth step response (ζ = 1/√2, ω = 2π rad/s)
    z, w = 1 / np.sqrt(2), 2 * np.pi
    wd = w * np.sqrt(1 - z * z)
    for t in (0.1, 0.25, 0.5, 1.0):
        ref = 1 - np.exp(-z * w * t) * (np.cos(wd * t) + z / np.sqrt(1 - z * z) * np.sin(wd * t))
        assert values[round(t * 100) - 1] == pytest.approx(100 * ref, abs=3.0)
    assert values[-1] == pytest.approx(100.0, rel=1e-3)
    assert f.value_g[1] == 0.0  # an unsampled world keeps its state


def test_weight_filter_is_scipy_sosfilt_per_world() -> None:
    """Worlds sampled at different instants (a vector env's worlds reset at different steps)
    each get exactly what scipy's sosfilt makes of that world's own sample sequence."""
    rng = np.random.default_rng(3)
    f = WeightFilter(3, order=4, noise_n=0.15)  # two sections: the recurrence chains them
    tare = np.array([1.0, 2.0, 0.5])
    for w in range(3):
        f.reset(w, tare[w])
    fed: list[list[float]] = [[], [], []]
    for _ in range(300):
        worlds = np.flatnonzero(rng.random(3) < 0.6)
        force, noise = rng.normal(3.0, 1.0, len(worlds)), rng.standard_normal(len(worlds))
        f.sample(worlds, force, noise)
        for k, w in enumerate(worlds):
            fed[w].append((force[k] - tare[w] + 0.15 * noise[k]) / GRAVITY * 1e3)
    for w in range(3):
        assert len(fed[w]) > 100
        assert f.value_g[w] == pytest.approx(signal.sosfilt(f.sos, fed[w])[-1], rel=1e-12)


def test_weight_filter_noise_level() -> None:
    noise_n = 0.15
    f = WeightFilter(1, noise_n=noise_n)
    f.reset(0, 0.0)
    rng = np.random.default_rng(0)
    out = []
    for _ in range(20000):
        f.sample(np.array([0]), np.zeros(1), rng.standard_normal(1))
        out.append(f.value_g[0])
    # white noise through the filter: σ_out = σ_in · sqrt(Σ h²) over the impulse response
    impulse = signal.sosfilt(f.sos, np.r_[1.0, np.zeros(5000)])
    expected = noise_n / GRAVITY * 1e3 * np.sqrt(np.sum(impulse**2))
    assert np.std(out[500:]) == pytest.approx(expected, rel=0.15)
    assert 1.0 < expected < 4.0  # about the robot's reported ±2 g


def test_default_curriculum() -> None:
    lessons = load_curriculum()
    assert [lesson.fraction for lesson in lessons] == [0.25, 0.25, 0.5]
    for key in ("adhesion", "viscosity_pa_s"):
        mids = [np.mean(lesson.ranges[key]) for lesson in lessons]
        assert mids == sorted(mids) and mids[0] < mids[-1]
    rng = np.random.default_rng(1)
    for lesson in lessons:
        for _ in range(5):
            liq = lesson.sample(rng)
            for key, (lo, hi) in lesson.ranges.items():
                assert lo <= getattr(liq, key) <= hi
    # the viscosity is log-uniform: half the draws of the last lesson below the geometric mean
    lo, hi = lessons[2].ranges["viscosity_pa_s"]
    draws = np.array([lessons[2].sample(rng).viscosity_pa_s for _ in range(400)])
    assert np.mean(draws < np.sqrt(lo * hi)) == pytest.approx(0.5, abs=0.08)
    assert [lesson_at(p, lessons) for p in (0.0, 0.3, 0.6, 1.0)] == [0, 1, 2, 2]
    # a last rollout past its budget stays in the last lesson; NaN is refused, not read as past it
    assert lesson_at(1.02, lessons) == 2
    for bad in (float("nan"), -0.1, "half"):
        with pytest.raises(ValueError, match="progress must be"):
            lesson_at(bad, lessons)


GOOD_RANGES = {
    "density": "[900.0, 1100.0]",
    "adhesion": "[0.0, 0.001]",
    "cohesion": "[0.001, 0.002]",
    "surface_tension": "[0.0, 0.005]",
    "viscosity_pa_s": "[0.001, 0.003]",
}


@pytest.mark.parametrize(
    "change, words",
    [
        ({"density": "[1000.0, 900.0]"}, "key 'lesson[0].density': must be [low, high]"),
        ({"density": "[-100.0, 900.0]"}, "key 'lesson[0].density': must be > 0"),
        ({"viscosity_pa_s": "[-0.1, 0.05]"}, "key 'lesson[0].viscosity_pa_s': must be > 0"),
        ({"viscosity_pa_s": "[0.0, 0.05]"}, "key 'lesson[0].viscosity_pa_s': must be > 0"),
        ({"cohesion": "[0.001, nan]"}, "key 'lesson[0].cohesion': must be [low, high]"),
        ({"adhesion": None}, "key 'lesson[0].adhesion': must be [low, high]"),
        ({"fraction": None}, "key 'lesson[0].fraction': must be a number >= 0"),
        ({"fraction": '"half"'}, "key 'lesson[0].fraction': must be a number >= 0"),
        ({"density": "[900.0, 1100.0"}, "invalid TOML"),
    ],
)
def test_bad_curriculum_file_names_the_file_lesson_and_key(tmp_path, change, words) -> None:
    """Every malformed entry is refused when the file is read, with the file, the lesson and
    the key (not at an episode's reset, naming the base liquid)."""
    entries = {"fraction": "1.0", **GOOD_RANGES, **change}
    bad = tmp_path / "c.toml"
    body = "".join(f"{k} = {v}\n" for k, v in entries.items() if v is not None)
    bad.write_text("[[lesson]]\n" + body)
    with pytest.raises(ValueError) as exc:
        load_curriculum(bad)
    assert str(bad) in str(exc.value) and words in str(exc.value)
    good = tmp_path / "good.toml"
    good.write_text(
        "[[lesson]]\nfraction = 1.0\n" + "".join(f"{k} = {v}\n" for k, v in GOOD_RANGES.items())
    )
    assert load_curriculum(good)[0].ranges["density"] == (900.0, 1100.0)


def test_a_missing_or_unreadable_curriculum_file_is_named(tmp_path) -> None:
    for path in (tmp_path / "absent.toml", tmp_path):
        with pytest.raises(ValueError, match="cannot read") as exc:
            load_curriculum(path)
        assert str(path) in str(exc.value)
    latin = tmp_path / "latin1.toml"
    latin.write_bytes(b"# caf\xe9\n[[lesson]]\n")
    with pytest.raises(ValueError, match=str(latin)):
        load_curriculum(latin)
