"""Skill-CPD state machine on a scripted drop; network model; demonstrations."""

from __future__ import annotations

import numpy as np
import pytest

from pourbench.errors import InvalidParameterError
from pourbench.teleop import (
    DT_S,
    DeadlineDetector,
    NetworkModel,
    Outage,
    SkillCPD,
    SkillCPDConfig,
    SkillLibrary,
    closest_step,
    delta_sample,
    feeding_demos,
    letter_demos,
    random_outages,
    register_skill,
    task_outage,
)


@pytest.fixture(scope="module")
def library() -> SkillLibrary:
    lib = SkillLibrary(0.006).fit({L: [d.points for d in letter_demos(L, 10)] for L in "ACLS"})
    held_out = {L: [d.points for d in letter_demos(L, 3, start=20)] for L in "ACLS"}
    lib.calibrate(held_out)
    # the invariant mode is calibrated on what it is meant to absorb: rotated and scaled
    # operators (thesis Table 5.2's ranges), from the same held-out demonstrations
    varied = {
        L: [_vary(p, a, s) for p in ps for a, s in ((0, 1), (30, 1), (-30, 1), (0, 1.3), (0, 0.77))]
        for L, ps in held_out.items()
    }
    lib.calibrate(varied, invariant=True)
    return lib


def _vary(pts: np.ndarray, angle_deg: float, scale: float) -> np.ndarray:
    """``pts`` rotated by ``angle_deg`` and scaled by ``scale`` about its bounding-box centre."""
    a = np.deg2rad(angle_deg)
    R = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
    c = 0.5 * (pts.min(axis=0) + pts.max(axis=0))
    return (pts - c) @ R.T * scale + c


def _replay(lib, human, outage, **kw):
    net = NetworkModel([outage], DT_S)
    sa = SkillCPD(lib, SkillCPDConfig(**kw))
    robot, states, alphas = [], [], []
    for k in range(human.shape[0]):
        t = k * DT_S
        robot.append(sa.step(t, human[k] if net.delivered(t) else None))
        states.append(sa.state)
        alphas.append(sa.alpha)
    return sa, np.array(robot), states, np.array(alphas)


def _human(shift=(0.10, 0.0)) -> np.ndarray:
    return letter_demos("C", 1, start=10)[0].points + np.array(shift)


def test_scripted_drop_direct_skill_handback_direct(library: SkillLibrary) -> None:
    human = _human()
    k_drop, k_back = 300, 300 + 45  # 1.5 s outage from t = 9.9 s
    outage = Outage(k_drop * DT_S - 1e-6, (k_back - k_drop) * DT_S)
    sa, robot, states, alphas = _replay(library, human, outage)
    # direct until the drop; the first missed packet is within the 50 ms deadline (hold),
    # the second one is past it and triggers the switch
    assert all(s == "direct" for s in states[:k_drop])
    np.testing.assert_allclose(robot[:k_drop], human[:k_drop])
    assert states[k_drop] == "direct" and np.allclose(robot[k_drop], robot[k_drop - 1])
    assert states[k_drop + 1] == "skill"
    assert all(s == "skill" for s in states[k_drop + 1 : k_back])
    assert [(a, b) for _, a, b in sa.transitions] == [
        ("direct", "skill"),
        ("skill", "handback"),
        ("handback", "direct"),
    ]
    reg = sa.registrations[0]
    assert reg.label == "C" and reg.confidence >= 0.9
    assert reg.kind in ("rigid", "nonrigid")
    # alpha ramps 0.1, 0.2, ..., 1.0 over the 10 packets after reconnection
    np.testing.assert_allclose(alphas[k_back : k_back + 10], np.arange(1, 11) / 10, atol=1e-9)
    assert states[k_back + 9] == "direct"
    assert all(s == "direct" for s in states[k_back + 9 :])
    np.testing.assert_allclose(robot[k_back + 9 :], human[k_back + 9 :])
    # during the ramp the command blends the skill and the operator
    a = alphas[k_back + 4]
    skill_pt = (robot[k_back + 4] - a * human[k_back + 4]) / (1 - a)
    assert np.min(np.linalg.norm(reg.trajectory - skill_pt, axis=1)) < 2e-3
    # the robot keeps moving during the outage, and without a jump at the switch
    moved = np.linalg.norm(robot[k_back - 1] - robot[k_drop])
    assert moved > 0.5 * 1.5 * 0.04  # at least half the operator's ~5 cm/s mean speed
    assert np.linalg.norm(robot[k_drop + 1] - robot[k_drop]) < 0.01


def test_registration_beats_unregistered_skill_on_a_shifted_letter(library) -> None:
    human = _human(shift=(0.10, 0.0))
    outage = Outage(300 * DT_S - 1e-6, 1.5)
    jumps = {}
    for mode in ("standard", "skill_cpd"):
        sa, robot, _, _ = _replay(library, human, outage, mode=mode)
        assert sa.registrations, mode
        jumps[mode] = np.linalg.norm(robot[301] - robot[300])
    assert jumps["skill_cpd"] < 0.01
    assert jumps["standard"] > 0.05  # the unregistered skill is 10 cm away


def test_the_takeover_offset_fades_linearly_onto_the_registered_skill(library) -> None:
    # the robot is off the registered skill by the registration's residual at the switch:
    # with takeover_step 1 (the thesis) it jumps onto the skill, with 0.1 each packet from
    # the switch on removes a tenth of that offset, so the command reaches the same skill
    # points 10 packets later
    human = _human(shift=(0.10, 0.0))
    outage = Outage(300 * DT_S - 1e-6, 1.5)
    jump, ref, _, _ = _replay(library, human, outage, takeover_step=1.0)
    fade, robot, states, _ = _replay(library, human, outage, takeover_step=0.1)
    assert states[301] == "skill" and all(s == "skill" for s in states[301:345])
    np.testing.assert_array_equal(
        fade.registrations[0].trajectory, jump.registrations[0].trajectory
    )
    offset = robot[300] - ref[301]
    assert np.linalg.norm(offset) > 1e-4  # the residual is real, not zero
    for k in range(11):
        weight = max(0.0, 1.0 - (k + 1) / 10)
        np.testing.assert_allclose(robot[301 + k], ref[301 + k] + weight * offset, atol=1e-9)
    np.testing.assert_allclose(robot[310:345], ref[310:345], atol=1e-12)


def test_a_speed_limited_handback_closes_the_gap_no_faster_than_its_speed(library) -> None:
    # the hand-back command (1 - alpha) skill + alpha operator moves by the rise of alpha
    # times the skill-operator gap on top of their own motion: with handback_speed that
    # part is capped at handback_speed * dt a packet, so alpha rises more slowly than 0.1
    human = _human()
    k_back = 300 + 90  # a 3 s outage leaves the skill centimetres off the operator
    outage = Outage(300 * DT_S - 1e-6, 90 * DT_S)
    speed = 0.015
    sa, robot, states, alphas = _replay(library, human, outage, handback_speed=speed)
    assert sa.registrations and states[k_back] == "handback"
    k_end = states.index("direct", k_back)
    assert k_end > k_back + 10  # slower than the thesis' 10-packet ramp
    for k in range(k_back, k_end):
        a = alphas[k]
        skill_point = (robot[k] - a * human[k]) / (1.0 - a)
        gap = np.linalg.norm(human[k] - skill_point)
        rise = a - (alphas[k - 1] if k > k_back else 0.0)
        np.testing.assert_allclose(rise, min(0.1, speed * DT_S / gap), rtol=1e-9)
        assert rise * gap <= speed * DT_S * (1 + 1e-9)
    np.testing.assert_allclose(robot[k_end:], human[k_end:])


def test_no_shared_autonomy_holds_then_jumps(library: SkillLibrary) -> None:
    human = _human()
    outage = Outage(300 * DT_S - 1e-6, 45 * DT_S)  # packets 300 .. 344 are lost
    sa, robot, states, _ = _replay(library, human, outage, mode="none")
    assert not sa.registrations
    assert all(s == "hold" for s in states[301:345])
    assert np.allclose(robot[300:345], robot[299])
    np.testing.assert_allclose(robot[345:], human[345:])


def test_a_letter_outside_the_library_never_switches(library: SkillLibrary) -> None:
    # O is not in the library (A, C, L, S): its calibrated confidence is low at the drop,
    # so the robot holds its last command as without shared autonomy
    human = letter_demos("O", 1, start=10)[0].points + np.array([0.10, 0.0])
    outage = Outage(300 * DT_S - 1e-6, 1.0)
    sa, robot, states, _ = _replay(library, human, outage)
    assert not sa.registrations and "skill" not in states
    assert sa.recognitions[0][1].confidence < 0.9
    assert np.all(robot[300:330] == robot[299])


def test_closest_step_window() -> None:
    traj = np.c_[np.linspace(0, 1, 101), np.zeros(101)]
    assert closest_step(np.array([0.5, 0.0]), traj, 50, 10) == 50
    assert closest_step(np.array([0.9, 0.0]), traj, 50, 10) == 60  # clipped to the window
    assert closest_step(np.array([0.0, 0.0]), traj, 100, 5) == 95


def test_closest_step_window_before_the_start_searches_the_start() -> None:
    """``centre ± window`` wholly before index 0 searches the first points, as one wholly
    past the end searches the last ones (not the far end of the trajectory)."""
    traj = np.c_[np.linspace(0, 1, 101), np.zeros(101)]
    assert closest_step(np.array([0.0, 0.0]), traj, -100, 2) == 0
    assert closest_step(np.array([1.0, 0.0]), traj, -3, 2) == 2  # clipped to [0, 2]
    assert closest_step(np.array([0.0, 0.0]), traj, 500, 2) == 98


def test_closest_step_refuses_non_finite_traj_outside_the_window() -> None:
    traj = np.c_[np.linspace(0, 1, 50), np.zeros(50)]
    traj[40] = np.nan
    with pytest.raises(InvalidParameterError, match="traj contains NaN"):
        closest_step(np.array([0.06, 0.0]), traj, 3, 2)


def test_register_skill_refuses_non_finite_points_in_every_mode(library) -> None:
    xa = library.skill("A").trajectory
    X = xa[:40].copy()
    X[5] = np.nan
    ok = xa[:40]
    for mode in ("standard", "skill_cpd"):
        cfg = SkillCPDConfig(mode=mode)
        with pytest.raises(InvalidParameterError, match="X contains NaN"):
            register_skill(X, xa, xa[39], cfg)
        bad = xa.copy()
        bad[-1, 0] = np.inf
        with pytest.raises(InvalidParameterError, match="xi_a contains NaN or infinite"):
            register_skill(ok, bad, xa[39], cfg)


def test_deadline_detector_and_network() -> None:
    det = DeadlineDetector(0.050)
    assert not det.disconnected(1.0)  # nothing received yet
    det.packet(1.0)
    assert not det.disconnected(1.033)
    assert det.disconnected(1.066)
    net = NetworkModel([Outage(2.0, 1.0)])
    assert net.delivered(1.99) and not net.delivered(2.0) and not net.delivered(2.99)
    assert net.delivered(3.0)
    rng = np.random.default_rng(0)
    for _ in range(50):
        o = task_outage(rng, 20.0)
        assert 8.0 <= o.start <= 12.0 and 0.5 <= o.duration <= 5.0


def test_demonstrations_are_deterministic_and_human_like() -> None:
    a = letter_demos("Q", 3, seed=5)
    b = letter_demos("Q", 3, seed=5)
    for x, y in zip(a, b, strict=True):
        np.testing.assert_array_equal(x.points, y.points)
    assert not np.allclose(a[0].points[:100], a[1].points[:100])
    held = letter_demos("Q", 1, seed=5, start=2)[0]
    np.testing.assert_array_equal(held.points, a[2].points)
    n = [delta_sample(d.points, 0.006).shape[0] for d in letter_demos("M", 10)]
    assert 140 <= np.mean(n) <= 180
    durations = [d.t[-1] for d in letter_demos("M", 10)]
    assert np.std(durations) > 0.1  # timing varies between demonstrations
    f = feeding_demos("left", 2)
    assert f[0].points.shape[1] == 3
    assert 150 <= delta_sample(f[0].points, 0.01).shape[0] <= 250
    s = delta_sample(a[0].points, 0.006)
    assert np.all(np.linalg.norm(np.diff(s, axis=0), axis=1) >= 0.006)


def test_malformed_input_raises_value_error(library: SkillLibrary) -> None:
    sa = SkillCPD(library)
    with pytest.raises(ValueError, match="no packet"):
        sa.step(0.0, None)
    sa.step(0.0, np.array([0.0, 0.0]))
    with pytest.raises(ValueError, match="finite"):
        sa.step(0.033, np.array([np.nan, 0.0]))
    with pytest.raises(ValueError, match="dims"):
        sa.step(0.066, np.array([0.0, 0.0, 0.0]))
    with pytest.raises(ValueError, match="mode"):
        SkillCPDConfig(mode="auto")
    with pytest.raises(ValueError, match="letter"):
        letter_demos("3")
    with pytest.raises(ValueError, match="points"):
        delta_sample(np.zeros((0, 2)), 0.006)
    with pytest.raises(ValueError, match="NaN"):
        library.recognize(np.array([[0.0, 0.0], [np.nan, 1.0]]))
    with pytest.raises(ValueError, match="no demonstrations"):
        SkillLibrary(0.006).fit({"A": []})


@pytest.mark.parametrize(
    ("delta_d", "match"),
    [
        (np.inf, r"delta_d must be finite, got inf"),
        (np.nan, r"delta_d must be finite"),
        ("0.01", r"delta_d must be a number, got '0.01'"),
        (0.0, r"delta_d must be > 0"),
    ],
)
def test_delta_sample_refuses_bad_delta_d(delta_d, match) -> None:
    with pytest.raises(InvalidParameterError, match=match):
        delta_sample(np.zeros((3, 2)), delta_d)


def test_invariant_recognition_handles_rotated_and_scaled_operators(library) -> None:
    for L in "ACLS":
        raw = letter_demos(L, 1, start=10)[0].points
        c = 0.5 * (raw.min(axis=0) + raw.max(axis=0))
        a = np.deg2rad(30.0)
        R = np.array([[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]])
        for pts in ((raw - c) @ R.T + c, (raw - c) * 1.3 + c):
            s = delta_sample(pts, 0.006)
            rec = library.recognize(s[: int(0.45 * s.shape[0])], invariant=True)
            assert rec.label == L and rec.calibrated and rec.confidence > 0.9


_RNG = np.random.default_rng


@pytest.mark.parametrize(
    ("call", "match"),
    [
        # zero / tiny means would never advance the clock (a hang)
        (lambda: random_outages(_RNG(0), 10.0, mean_up=0.0, mean_down=0.0), "mean_up"),
        (lambda: random_outages(_RNG(0), 10.0, mean_down=0.0), "mean_down must be > 0"),
        (lambda: random_outages(_RNG(0), 10.0, max_down=0.0), "max_down must be > 0"),
        (lambda: random_outages(_RNG(0), 10.0, mean_up=np.nan), "mean_up must be finite"),
        (lambda: task_outage(_RNG(0), 10.0, after_fraction=np.nan), "after_fraction"),
        (lambda: task_outage(_RNG(0), 10.0, after_fraction=2, latest_fraction=3), "<= 1"),
        (lambda: task_outage(_RNG(0), 10.0, after_fraction=0.9, latest_fraction=0.1), "after"),
        (lambda: task_outage(_RNG(0), 10.0, min_duration=8.0, max_duration=1.0), "max_dur"),
        (lambda: DeadlineDetector().packet(np.nan), "t must be finite"),
        (lambda: NetworkModel([(2.0, 1.0)]), r"outages\[0\] must be an Outage"),
        (lambda: SkillCPDConfig(cpd_w=1.5), "cpd_w"),
        (lambda: SkillCPDConfig(beta=0), "beta must be > 0"),
        (lambda: SkillCPDConfig(lmbda=-1), "lmbda must be > 0"),
        (lambda: SkillCPDConfig(cpd_max_iter=2.5), "cpd_max_iter must be an integer"),
        (lambda: SkillCPDConfig(window=2.5), "window must be an integer"),
        (lambda: SkillCPDConfig(window=np.nan), "window must be an integer"),
        (lambda: SkillCPDConfig(min_confidence=2.0), "min_confidence must be in"),
        (lambda: SkillCPDConfig(cpd_tol=np.nan), "cpd_tol must be finite"),
        (lambda: SkillCPDConfig(takeover_step=0.0), "takeover_step must be > 0"),
        (lambda: SkillCPDConfig(takeover_step=1.5), "takeover_step .* must be in"),
        (lambda: SkillCPDConfig(handback_speed=-0.01), "handback_speed must be >= 0"),
        (lambda: SkillCPDConfig(handback_speed=np.inf), "handback_speed must be finite"),
        (lambda: SkillCPD(SkillLibrary(0.006)), "no skills"),
        (lambda: closest_step(np.full(2, np.nan), np.zeros((20, 2)), 5, 3), "point"),
        (lambda: closest_step(np.zeros(2), np.zeros((20, 2)), 5, -5), "window must be >= 0"),
        (lambda: closest_step(np.zeros(2), np.full((20, 2), np.nan), 5, 3), "traj contains NaN"),
        (lambda: letter_demos("A", -1), "n must be >= 0"),
        (lambda: letter_demos("A", 2.5), "n must be an integer"),
        (lambda: letter_demos("A", 1, seed=1.7), "seed must be an integer"),
        (lambda: letter_demos("A", 1, start=0.5), "start must be an integer"),
        (lambda: feeding_demos("left", -2), "n must be >= 0"),
        (lambda: SkillLibrary(0.006, n_states=2.5), "n_states must be an integer"),
        (lambda: SkillLibrary(0.006, reg=np.nan), "reg must be finite"),
        (
            lambda: SkillLibrary(0.006).fit({"A": [np.zeros((3, 2))], "B": [np.zeros((3, 3))]}),
            "dim",
        ),
    ],
)
def test_bad_settings_are_refused_up_front(call, match) -> None:
    with pytest.raises(InvalidParameterError, match=match):
        call()


def test_random_outages_with_valid_means_still_work() -> None:
    out = random_outages(_RNG(0), 60.0)
    assert out and all(o.duration <= 5.0 for o in out)


def test_refused_step_changes_nothing(library: SkillLibrary) -> None:
    human = _human()
    sa = SkillCPD(library)
    for k in range(200):
        sa.step(k * DT_S, human[k])
    snap = (sa.state, sa.position.copy(), len(sa.history), sa.detector.last_rx)
    for t, p in ((np.nan, human[200]), (np.inf, None), (200 * DT_S, np.zeros(0))):
        with pytest.raises(InvalidParameterError, match=r"t must be finite|non-empty"):
            sa.step(t, p)
        assert (sa.state, len(sa.history), sa.detector.last_rx) == (snap[0], *snap[2:])
        np.testing.assert_array_equal(sa.position, snap[1])
    # disconnect detection still works after the refused NaN time
    for k in range(200, 203):
        sa.step(k * DT_S, None)
    assert sa.state == "skill"


def test_step_refuses_time_going_back_and_changes_nothing(library: SkillLibrary) -> None:
    """A clock stepping back would count the path since then over a negative time and
    inflate the operator's speed (which drives the skill during an outage)."""
    human = _human()
    sa = SkillCPD(library)
    for k in range(30):
        sa.step(1.0 + k * DT_S, human[k])
    snap = (sa.state, len(sa.history), sa.detector.last_rx, sa._speed(), sa.position.copy())
    for p in (human[30], None):
        with pytest.raises(InvalidParameterError, match=r"t must not go back: 0\.5 s"):
            sa.step(0.5, p)
        now = (sa.state, len(sa.history), sa.detector.last_rx, sa._speed(), sa.position)
        assert now[:4] == snap[:4]
        np.testing.assert_array_equal(now[4], snap[4])
    t_last = 1.0 + 29 * DT_S
    sa.step(t_last, None)  # the same time again is allowed
    with pytest.raises(InvalidParameterError, match="t must not go back"):
        sa.step(t_last - 1e-3, None)  # a packet-less step counts as well
    sa.step(t_last + DT_S, human[30])
    assert sa._speed() == pytest.approx(snap[3], rel=0.2)


def test_a_refitted_library_refuses_to_switch_and_changes_nothing(library) -> None:
    """Refitting drops the calibrations; an uncalibrated recognition (confidence about 1 for
    any letter, here Z, not in the library) must not switch to a skill."""
    import copy

    lib = copy.deepcopy(library)
    sa = SkillCPD(lib)
    lib.fit({"A": [d.points for d in letter_demos("A", 4)]})
    assert lib.calibration() is None
    human = letter_demos("Z", 1, start=20)[0].points
    for k in range(100):
        sa.step(k * DT_S, human[k])
    sa.step(100 * DT_S, None)  # within the deadline
    snap = (sa.state, len(sa.history), len(sa.recognitions), list(sa.transitions))
    for _ in range(2):
        with pytest.raises(InvalidParameterError, match=r"recognised skill '\w' .*calibrate"):
            sa.step(101 * DT_S, None)
        assert (sa.state, len(sa.history), len(sa.recognitions), sa.transitions) == snap
    assert not sa.registrations and sa.state == "direct"


def test_packet_dimension_must_match_the_skills(library: SkillLibrary) -> None:
    with pytest.raises(InvalidParameterError, match="the skills have 2"):
        SkillCPD(library).step(0.0, np.zeros(3))


def test_recognize_refuses_bad_alignment_limits(library: SkillLibrary) -> None:
    pts = delta_sample(_human()[:200], 0.006)
    with pytest.raises(InvalidParameterError, match="max_scale"):
        library.recognize(pts, invariant=True, max_scale=0)
    with pytest.raises(InvalidParameterError, match="max_scale"):
        library.recognize(pts, invariant=True, max_scale=-1)
    with pytest.raises(InvalidParameterError, match="max_rotation_deg"):
        library.recognize(pts, invariant=True, max_rotation_deg=np.nan)
    with pytest.raises(InvalidParameterError, match="max_rotation_deg"):
        library.recognize(pts, invariant=True, max_rotation_deg=-5)
    with pytest.raises(InvalidParameterError, match="identical"):
        library.recognize(np.ones((10, 2)), invariant=True)


def test_register_skill_refuses_a_one_point_skill(library: SkillLibrary) -> None:
    X = delta_sample(_human()[:150], 0.006)
    xa = library.skill("C").trajectory
    with pytest.raises(InvalidParameterError, match="xi_a"):
        register_skill(X, xa[:1], X[-1], SkillCPDConfig())
    with pytest.raises(InvalidParameterError, match="X must be"):
        register_skill(X[:1], xa, X[0], SkillCPDConfig())


def test_failed_library_fit_is_atomic() -> None:
    lib = SkillLibrary(0.006, n_states=3)
    lib.fit({L: [d.points[::4] for d in letter_demos(L, 2)] for L in "AC"})
    pts = delta_sample(letter_demos("C", 1, start=10)[0].points, 0.006)[:60]
    before = lib.recognize(pts)
    traj_a = lib.skill("A").trajectory.copy()
    new_a = [d.points[::4] for d in letter_demos("C", 2, start=20)]
    with pytest.raises(InvalidParameterError, match="skill 'C'"):
        lib.fit({"A": new_a, "C": [pts[:1]]})
    with pytest.raises(InvalidParameterError, match="same dimension"):
        lib.fit({"A": new_a, "F": [np.c_[pts, pts[:, 0]]]})
    assert lib.labels == ["A", "C"]
    np.testing.assert_array_equal(lib.skill("A").trajectory, traj_a)
    lib._cache.clear()  # recompute: the skills themselves must be unchanged
    assert lib.recognize(pts) == before


def test_registration_resuming_the_recognition_alignment_matches_a_cold_one(library) -> None:
    cfg = SkillCPDConfig(invariant_recognition=True)
    for L in "ACS":
        X = delta_sample(_vary(letter_demos(L, 1, start=11)[0].points, 30, 1.0), 0.006)
        X = X[: int(0.45 * X.shape[0])]
        rec = library.recognize(X, invariant=True)
        assert rec.alignment is not None and rec.label == L
        xa = library.skill(L).trajectory
        warm = register_skill(X, xa, X[-1], cfg, rec.alignment)
        cold = register_skill(X, xa, X[-1], cfg)
        assert warm[1:2] == cold[1:2] and warm[3] == cold[3]  # kind, closest step
        np.testing.assert_allclose(warm[0], cold[0], atol=1e-6)
