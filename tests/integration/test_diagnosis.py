"""Per-throw estimation, isolation and offline diagnosis (issue 4)."""
import dataclasses
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from railswitch.models.diagnosis.estimation import Measurement
from railswitch.models.reduced.hybrid import PARAMETERS
from railswitch.models.plant.reference import throw_reference
from railswitch.models.plant.signals import MotorSignals
from railswitch.models.plant.simulation import SwitchSimulation
from railswitch.schemas import Diagnosis, MotorSample, ThrowEvent, decode
from railswitch.schemas.faults import FAULT_PARAMETERS
from railswitch.services.adapters.recordings import load_recording
from railswitch.services.core.fleet_diagnoser import diagnose_messages, diagnose_simulation
from railswitch.services.wiring import Diagnoser
from railswitch.services.core.throw_cutter import cut_throws

RECORDINGS = Path(__file__).resolve().parents[2] / "recordings"


def diagnose(diagnoser: Diagnoser, messages) -> list[Diagnosis]:
    diagnoser.switches.clear()
    return [item.diagnosis for item in diagnose_messages(messages, diagnoser)]


@pytest.mark.parametrize("scenario", ["left_bolt", "right_bolt", "missing_bearing", "obstacle"])
def test_paper_scenario_is_decided_correctly(diagnoser, scenario):
    recording = load_recording(RECORDINGS / f"{scenario}.mcap")
    assert recording.note() is None
    messages = recording.messages
    diagnoses = diagnose(diagnoser, messages)
    assert [d.throw_index for d in diagnoses] == [0, 1]
    assert diagnoses[-1].decision == scenario, diagnoses[-1].reason


def test_nominal_recording_is_nominal(diagnoser):
    messages = load_recording(RECORDINGS / "nominal.mcap").messages
    assert [d.decision for d in diagnose(diagnoser, messages)] == ["nominal", "nominal"]


@pytest.mark.parametrize("seed", [11, 12])
def test_nominal_throws_with_one_percent_noise_are_nominal(diagnoser, plant, seed):
    sim = SwitchSimulation(plant, noise_rel=0.01, seed=seed)
    diagnoser.switches.clear()
    assert [item.diagnosis.decision for item in diagnose_simulation(diagnoser, "noisy", sim, 2)] == ["nominal", "nominal"]


def _twin_throw(estimator, direction: str, truth: dict[str, float]) -> Measurement:
    """The reduced model's own throw under `truth`, the switch as built."""
    start_rail = 1.0 if direction == "left_to_right" else 1.2
    start_angle = 0.0 if direction == "left_to_right" else float(throw_reference("left_to_right").angle_rad())
    reference, t_s = throw_reference(direction), np.arange(1, 351) / 50.0
    blank = np.zeros(350)
    y = estimator.simulate(Measurement(direction, reference, t_s, MotorSignals(blank, blank, blank), start_angle,
                                       start_rail), truth)
    return Measurement(direction, reference, t_s, MotorSignals(y["current_a"], y["angle_rad"], y["velocity_rad_s"]),
                       start_angle, start_rail)


@pytest.mark.parametrize("direction, mode, truth", [
    ("left_to_right", "left_bolt", {"left_bolt_offset": 0.07}),
    ("right_to_left", "right_bolt", {"right_bolt_offset": 0.12}),
    ("left_to_right", "missing_bearing", {"bearing_friction": 4000.0}),
    ("right_to_left", "obstacle", {"obstacle_friction": 8e4, "obstacle_position": 1.13}),
])
def test_single_fault_is_identified_within_a_tenth_of_a_percent_on_reduced_model_data(diagnoser, direction, mode, truth):
    """The reduced model's own throw (its twin): every hypothesis fitted as the diagnosis fits it, the switch as
    built (the reduced model's nominal own parameters)."""
    estimator = diagnoser.estimator
    m = _twin_throw(estimator, direction, truth)
    estimates = estimator.fit_all(m, diagnoser.switch("twin").specs(direction))
    for name, value in truth.items():
        assert estimates[mode].params[name] == pytest.approx(value, rel=1e-3), estimates[mode]
    assert estimates[mode].mse < 1e-3 * estimates["nominal"].mse


def test_once_a_fault_is_shown_the_modes_that_cannot_beat_it_stop_and_it_is_fitted_as_before(diagnoser, monkeypatch):
    """The mode whose start fits best is fitted first; once `decide` shows it, the fault modes fitted after it stop
    where they cannot beat it (models/diagnosis/estimation.py HOPELESS_MARGIN): each still above it, no more Jacobians and
    rollouts in all, and the shown fault fitted to the bit as when every fit runs to its end. On the twin's throw the
    rival test already stops most of them; fitted alone from the nominal fit, each stops at its first linearisation
    where it runs on without `beaten`."""
    estimator = diagnoser.estimator
    m = _twin_throw(estimator, "right_to_left", {"obstacle_friction": 8e4, "obstacle_position": 1.13})
    specs = diagnoser.switch("twin").specs("right_to_left")
    calls = []
    for name in ("linearise", "residuals"):
        monkeypatch.setattr(estimator, name,
                            lambda *a, _f=getattr(estimator, name), **k: calls.append(1) or _f(*a, **k))
    whole = estimator.fit_all(m, specs)
    spent = len(calls)
    seen = []

    def decide(fits):
        seen.append(list(fits))
        return "obstacle" if "obstacle" in fits else "nominal"

    judged = estimator.fit_all(m, specs, decide=decide)
    assert seen[1] == ["nominal", "obstacle"]
    assert judged["obstacle"].params == whole["obstacle"].params
    others = [mode for mode in specs if mode not in ("nominal", "obstacle", "joint")]
    assert len(calls) - spent <= spent
    assert all(judged[mode].objective > judged["obstacle"].objective for mode in others)
    assert list(judged) == list(whole)  # in the specs' order, whichever was fitted first
    throw, weight = estimator.prepare(m), whole["nominal"].prior_weight
    for mode in others:
        calls.clear()
        estimator.fit(specs[mode], throw, whole["nominal"].values, prior_weight=weight)
        free = len(calls)
        calls.clear()
        stopped = estimator.fit(specs[mode], throw, whole["nominal"].values, prior_weight=weight,
                                beaten=whole["obstacle"].objective)
        assert len(calls) < free or free == 1, mode
        assert stopped.objective > whole["obstacle"].objective


def test_the_joint_fit_starts_where_the_best_mode_joined_with_another_modes_own_fit_fits_best(diagnoser, monkeypatch):
    """From the best mode's fit alone, the joint fit's obstacle starts at no friction, where its position has no
    slope: on population switches with a missing bearing it crept for 12 iterations on average, a small obstacle
    absorbing model error, to a worse end than from the best mode joined with the obstacle's own fit (4 iterations).
    The candidates are the best mode's fit, it joined with each other mode's own parameters, and the switch's
    previous joint fit; the lowest objective starts it."""
    estimator = diagnoser.estimator
    m = _twin_throw(estimator, "left_to_right", {"bearing_friction": 4000.0})
    specs = diagnoser.switch("twin").specs("left_to_right")
    offered = []
    lowest = estimator._lowest_start
    monkeypatch.setattr(estimator, "_lowest_start", lambda spec, throw, weight, candidates:
                        offered.append(candidates) or lowest(spec, throw, weight, candidates))
    fits = estimator.fit_all(m, specs)
    (candidates,) = offered
    best = min(("left_bolt", "missing_bearing", "obstacle", "drive_friction"), key=lambda mode: fits[mode].objective)
    assert best == "missing_bearing" and candidates[0] == fits[best].values
    joined = [c for c in candidates[1:] if c["obstacle_friction"] == fits["obstacle"].values["obstacle_friction"]]
    assert joined and joined[0]["bearing_friction"] == fits[best].values["bearing_friction"]
    throw = estimator.prepare(m)
    chosen = lowest(specs["joint"], throw, 0.0, candidates)
    objectives = [estimator.cost(estimator._start(specs["joint"], c)[0], throw) for c in candidates]
    assert chosen is candidates[int(np.argmin(objectives))]


def test_the_nominal_fit_starts_from_the_linearisation_that_chose_its_start(diagnoser):
    """The nominal fit's start is chosen as _lowest_start chooses between the nominal values and the previous fit
    (warm); where warm wins, its residual and Jacobian, computed to judge it, start the fit, which ends where it
    ends computing them again, bit for bit. Where the nominal values win, the fit computes its own."""
    estimator = diagnoser.estimator
    specs = diagnoser.switch("twin").specs("left_to_right")
    spec, weight = specs["nominal"], 1e-6
    previous = estimator.fit_all(_noisy(_twin_throw(estimator, "left_to_right", {"motor.resistance_ohm": 10.4}), 1),
                                 specs)["nominal"].values
    throw = estimator.prepare(_noisy(_twin_throw(estimator, "left_to_right", {"motor.resistance_ohm": 10.5}), 2))
    start, linearised = estimator._nominal_start(spec, throw, weight, previous)
    assert start is previous and linearised is not None
    assert estimator._lowest_start(spec, throw, weight, [{}, previous]) is previous
    theta, index = estimator._start(spec, previous)
    exact = estimator.linearise(theta, throw, index)
    assert all(np.array_equal(a, b) for a, b in zip(linearised, exact))
    reused = estimator.fit(spec, throw, start, prior_weight=weight, linearised=linearised)
    again = estimator.fit(spec, throw, start, prior_weight=weight)
    assert reused.values == again.values and reused.objective == again.objective
    assert reused.iterations == again.iterations and reused.std == again.std
    far = {name: high for name, (low, high) in spec.free.items()}  # every nuisance at its bound: a worse start
    assert estimator._nominal_start(spec, throw, weight, far) == ({}, None)
    assert estimator._lowest_start(spec, throw, weight, [{}, far]) == {}


@pytest.fixture(scope="module")
def causal_diagnoser() -> Diagnoser:
    d = Diagnoser("causal")
    d.warm_up()
    return d


@pytest.mark.parametrize("direction, truth", [("left_to_right", {"left_bolt_offset": 0.1325}),
                                              ("right_to_left", {"right_bolt_offset": 0.1125})])
def test_a_causal_bolt_between_grid_points_is_found_within_a_millimetre(causal_diagnoser, direction, truth):
    """The causal rail's bolt error surface was a sawtooth while its fine-tuning could move how its force depends
    on the acceleration (models/reduced/training.py): without the scan around the fit (HypothesisSpec.scanned) the solver
    stopped at a tooth's edge on these twin throws, 3.4 and 7.8 mm from the truth. Trained with that dependence
    held, the surface is smooth and the fit finds these bolts with or without the scan."""
    estimator = causal_diagnoser.estimator
    (name, value), = truth.items()
    mode = FAULT_PARAMETERS[name].mode
    estimates = estimator.fit_all(_twin_throw(estimator, direction, truth), causal_diagnoser.switch("twin").specs(direction))
    assert estimates[mode].params[name] == pytest.approx(value, abs=1e-3), estimates[mode]
    assert estimates[mode].mse < 1e-2 * estimates["nominal"].mse


def test_fits_started_from_the_previous_throws_need_fewer_iterations_and_a_start_that_fits_worse_is_not_taken(
        diagnoser):
    """The switch's previous fits (`warm`) start this throw's where they fit better than the cold starts: the
    same estimates in fewer iterations; starts far off (a bolt at its end stop, the winding twice as resistive
    and the point machine's friction three times its own) lose to the nominal values and the grid, and the fits
    are the cold ones to the bit."""
    estimator = diagnoser.estimator
    m = _twin_throw(estimator, "left_to_right", {"left_bolt_offset": 0.07})
    specs = diagnoser.switch("twin").specs("left_to_right")
    cold = estimator.fit_all(m, specs)
    warm = estimator.fit_all(m, specs, warm={mode: e.values for mode, e in cold.items()})
    assert sum(e.iterations for e in warm.values()) < sum(e.iterations for e in cold.values())
    assert warm["joint"].iterations < cold["joint"].iterations  # the joint fit too, not only the modes
    assert warm["left_bolt"].params["left_bolt_offset"] == pytest.approx(0.07, rel=1e-3)
    far = {mode: {**e.values, "left_bolt_offset": 0.19, "motor.resistance_ohm": 2 * e.values["motor.resistance_ohm"],
                  "motor.coulomb_friction_nm": 3 * e.values["motor.coulomb_friction_nm"]}
           for mode, e in cold.items()}
    farther = estimator.fit_all(m, specs, warm=far)
    for mode in ("nominal", "left_bolt", "joint"):
        assert farther[mode].params == cold[mode].params, mode


def _coarse_points(estimator, monkeypatch) -> list[int]:
    """How many points each grid ranking of the estimator evaluates, from now on."""
    counted, costs = [], estimator.costs

    def counting(thetas, throw, coarse=False):
        if coarse:
            counted.append(thetas.shape[1])
        return costs(thetas, throw, coarse)
    monkeypatch.setattr(estimator, "costs", counting)
    return counted


def test_a_settled_throw_starts_the_frictions_from_their_warm_fits_and_an_unsettled_one_runs_every_grid(
        diagnoser, monkeypatch):
    """Settled (the nominal fit within SETTLED of the previous healthy throw's): the bearing and drive-friction
    fits start from their warm values with no grid and end no worse than from it; the bolt ranks its warm value
    against its mark (0) and the obstacle a small one's positions against its warm fit (2 and 10 points); the
    same throw after one whose MSE was half this one's runs every grid (37 points and 4 warm)."""
    estimator = diagnoser.estimator
    m = _twin_throw(estimator, "left_to_right", {"left_bolt_offset": 0.004})
    specs = diagnoser.switch("twin").specs("left_to_right")
    previous = estimator.fit_all(m, specs)
    warm = {mode: e.values for mode, e in previous.items()}
    counted = _coarse_points(estimator, monkeypatch)
    settled = estimator.fit_all(m, specs, warm=warm, settled_mse=previous["nominal"].mse)
    unsettled = estimator.fit_all(m, specs, warm=warm, settled_mse=previous["nominal"].mse / 2)
    assert counted == [12, 41]
    for mode in ("missing_bearing", "drive_friction"):
        assert settled[mode].objective <= unsettled[mode].objective * (1 + 1e-3), mode


@pytest.mark.parametrize("direction, truth", [
    ("left_to_right", {"left_bolt_offset": 0.008}),
    ("right_to_left", {"right_bolt_offset": 0.008}),
    ("left_to_right", {"obstacle_friction": 4e4, "obstacle_position": 1.16}),
    ("right_to_left", {"obstacle_friction": 4e4, "obstacle_position": 1.04}),
    ("left_to_right", {"bearing_friction": 2500.0}),
    ("right_to_left", {"drive_friction_nm": 0.04}),
])
def test_a_new_fault_on_a_throw_that_counts_as_settled_is_fitted_as_the_grid_fits_it(diagnoser, direction, truth):
    """The risk of skipping a grid: a fault that appears without raising the nominal fit's MSE past SETTLED
    (on a real switch the model's error can dwarf a small one). Forced settled here, with the warm fits of a
    healthy throw, each mode fits the new fault as it does from its grid. An obstacle's fit to a healthy throw
    sits at an end of the travel with no friction, where its position has no slope: from there it does not find
    a new obstacle, so a settled throw ranks a small obstacle's positions (without them, both obstacle cases
    fail)."""
    estimator = diagnoser.estimator
    specs = diagnoser.switch("twin").specs(direction)
    healthy = estimator.fit_all(_twin_throw(estimator, direction, {}), specs)
    warm = {mode: e.values for mode, e in healthy.items()}
    m = _twin_throw(estimator, direction, truth)
    gridded = estimator.fit_all(m, specs, warm=warm)
    settled = estimator.fit_all(m, specs, warm=warm, settled_mse=np.inf)
    mode = FAULT_PARAMETERS[next(iter(truth))].mode
    for name in truth:
        assert settled[mode].params[name] == pytest.approx(gridded[mode].params[name], rel=1e-2), settled[mode]
    assert settled[mode].mse <= 1.01 * gridded[mode].mse


def _noisy(m: Measurement, seed: int, share: float = 0.01) -> Measurement:
    """`m` with white noise of `share` of each signal's range (one draw of the seed)."""
    rng = np.random.default_rng(seed)
    signals = [x + share * np.ptp(x) * rng.normal(size=x.size) for x in m.signals.matrix().T]
    return dataclasses.replace(m, signals=MotorSignals(*signals))


@pytest.mark.parametrize("direction", ["left_to_right", "right_to_left"])
def test_a_throw_whose_fits_start_where_the_previous_ones_ended_borrows_their_slopes(diagnoser, monkeypatch,
                                                                                      direction):
    """Two healthy throws (two draws of 1 % noise): on the second, settled, the fault modes' fits start where the
    first one's ended and take their first step with those fits' slopes. Half the Jacobians or fewer, and every
    hypothesis fitted as without them, within a hundredth of its standard deviation (its objective within the
    solver's tolerance); the nominal fit, which every test of a fault reads, as before to the bit. Not settled, no
    fit borrows."""
    estimator = diagnoser.estimator
    specs = diagnoser.switch("twin").specs(direction)
    healthy = _twin_throw(estimator, direction, {})
    previous = estimator.fit_all(_noisy(healthy, 1), specs)
    warm = {mode: e.values for mode, e in previous.items()}
    m, settled = _noisy(healthy, 2), previous["nominal"].mse
    counted, linearise = [], estimator.linearise
    monkeypatch.setattr(estimator, "linearise", lambda *args: counted.append(1) or linearise(*args))
    own = estimator.fit_all(m, specs, warm=warm, settled_mse=settled)
    jacobians = len(counted)
    slopes = {mode: e.slopes for mode, e in previous.items() if e.slopes is not None}
    assert set(slopes) == set(own) - {"nominal", "joint"}
    borrowed = estimator.fit_all(m, specs, warm=warm, settled_mse=settled, slopes=slopes)
    assert 2 * (len(counted) - jacobians) <= jacobians
    assert borrowed["nominal"].params == own["nominal"].params
    unsettled = [estimator.fit_all(m, specs, warm=warm, settled_mse=settled / 2, slopes=given)
                 for given in (slopes, None)]
    assert [e.params for e in unsettled[0].values()] == [e.params for e in unsettled[1].values()]
    for mode, estimate in own.items():
        assert borrowed[mode].objective == pytest.approx(estimate.objective, rel=1e-4), mode
        for name, value in estimate.params.items():
            assert abs(borrowed[mode].params[name] - value) <= 1e-2 * estimate.std[name], (mode, name)


def test_slopes_are_borrowed_only_at_the_point_signals_and_rate_they_were_made_for(diagnoser):
    """Kept unscaled (in half precision, each signal's slope over its largest), the slopes come back as the Jacobian
    of the throw they were made on to half precision's rounding (2^-11 of the largest), and of a throw a sample shorter
    or longer; not at another start, for other signals or another rate, nor once they are SLOPES_AGE throws old."""
    from railswitch.models.diagnosis.estimation import SLOPES_AGE, Slopes

    estimator = diagnoser.estimator
    m = _noisy(_twin_throw(estimator, "left_to_right", {}), 1)
    throw = estimator.prepare(m)
    free = list(diagnoser.switch("twin").specs("left_to_right")["missing_bearing"].free)
    index = [PARAMETERS.index(name) for name in free]
    theta = estimator.reduced.vector()
    _, jacobian = estimator.linearise(theta, throw, index)
    slopes = Slopes.of(jacobian, throw, free, theta[index], 0)
    rounding = 2.0**-11 * np.abs(jacobian).max(axis=0)  # per parameter
    assert np.all(np.abs(slopes.scaled(throw, free, theta[index]) - jacobian) <= rounding)
    for samples in (348, 349):
        shorter = estimator.prepare(dataclasses.replace(m, t_s=m.t_s[:samples], signals=m.signals[:samples]))
        assert slopes.scaled(shorter, free, theta[index]).shape == (3 * samples, len(free))
    longer = Slopes.of(estimator.linearise(theta, shorter, index)[1], shorter, free, theta[index], 0)
    extended, whole = (j.reshape(3, -1, len(free)) for j in (longer.scaled(throw, free, theta[index]), jacobian))
    assert np.all(np.abs(extended[:, :-1] - whole[:, :-1]) <= rounding)
    np.testing.assert_allclose(extended[:, -1], whole[:, -1], atol=1e-2 * np.abs(whole).max())  # its last, again
    moved = theta[index] * 1.001
    current = estimator.prepare(dataclasses.replace(m, signals=m.signals.only(("current_a",))))
    slower = estimator.prepare(dataclasses.replace(m, t_s=m.t_s * 2.0))
    assert slopes.scaled(throw, free, moved) is None
    assert slopes.scaled(current, free, theta[index]) is None and slopes.scaled(slower, free, theta[index]) is None
    assert dataclasses.replace(slopes, age=SLOPES_AGE).scaled(throw, free, theta[index]) is None


def test_a_throw_keeps_the_rollouts_its_fits_made_and_no_other_estimators(diagnoser, monkeypatch):
    """The model at a parameter vector already evaluated on the throw (a fit that starts where its candidate was
    judged, the decided fit's outputs) is not rolled out again; kept read only, and only for the estimator that made
    it (another one, here the same model uncompiled, rolls out its own)."""
    from railswitch.models.diagnosis.estimation import ThrowEstimator

    estimator = diagnoser.estimator
    throw = estimator.prepare(_noisy(_twin_throw(estimator, "left_to_right", {}), 1))
    theta = estimator.reduced.vector({"bearing_friction": 1500.0})
    first = estimator.all_outputs(theta, throw)
    calls, chunk = [], estimator._chunk
    monkeypatch.setattr(chunk, "views", lambda *args, views=chunk.views: calls.append(1) or views(*args))
    assert estimator.all_outputs(theta.copy(), throw) is first and not calls
    r = estimator.residuals(theta, throw)
    assert estimator.cost(theta, throw) == float(r @ r)
    assert not calls and not first.flags.writeable
    estimator.all_outputs(estimator.reduced.vector(), throw)
    assert calls
    other = ThrowEstimator(estimator.reduced, directions=(4,))
    assert other.all_outputs(theta, throw) is not first


@pytest.fixture(scope="module")
def throw_messages_of_one_recording():
    return load_recording(RECORDINGS / "left_bolt.mcap").messages


def _first_throw_span(messages):
    starts = [i for i, m in enumerate(messages) if isinstance(m, ThrowEvent) and m.phase == "start"]
    ends = [i for i, m in enumerate(messages) if isinstance(m, ThrowEvent) and m.phase == "end"]
    return starts[0], ends[0]


def _only_throw_zero(diagnoses):
    first = [d for d in diagnoses if d.throw_index == 0]
    assert len(first) == 1
    return first[0]


def _without_samples(messages, chosen: slice):
    """The messages less the first throw's samples picked by `chosen`."""
    start, end = _first_throw_span(messages)
    dropped = set([i for i in range(start, end) if isinstance(messages[i], MotorSample)][chosen])
    return [m for i, m in enumerate(messages) if i not in dropped]


def test_missing_samples_inside_a_throw_give_unknown_with_a_reason(diagnoser, throw_messages_of_one_recording):
    d = _only_throw_zero(diagnose(diagnoser, _without_samples(throw_messages_of_one_recording, slice(100, 103))))
    assert d.decision == "unknown" and "3 samples missing" in d.reason


def test_throw_cut_off_before_its_end_gives_unknown(diagnoser, throw_messages_of_one_recording):
    d = _only_throw_zero(diagnose(diagnoser, _without_samples(throw_messages_of_one_recording, slice(-120, None))))
    assert d.decision == "unknown" and "samples stop at" in d.reason


def test_throw_without_end_event_gives_unknown(diagnoser, throw_messages_of_one_recording):
    messages = list(throw_messages_of_one_recording)
    _, end = _first_throw_span(messages)
    diagnoses = diagnose(diagnoser, messages[:end])
    assert len(diagnoses) == 1
    assert diagnoses[0].decision == "unknown" and "no end event" in diagnoses[0].reason


def test_nan_values_give_unknown(diagnoser, throw_messages_of_one_recording):
    throw = next(cut_throws(throw_messages_of_one_recording))
    current = throw.signals.current_a.copy()
    current[50] = np.nan
    diagnoser.switches.clear()
    d = diagnoser.diagnose(dataclasses.replace(throw, signals=dataclasses.replace(throw.signals, current_a=current))).diagnosis
    assert d.decision == "unknown" and "non-finite" in d.reason


def test_diagnose_jsonl_prints_one_full_diagnosis_per_throw_in_order(tmp_path):
    result = subprocess.run([sys.executable, "-m", "railswitch", "diagnose", str(RECORDINGS / "obstacle.mcap"),
                             "--jsonl"], capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stderr
    lines = result.stdout.splitlines()
    diagnoses = [decode(Diagnosis, line.encode()) for line in lines]
    assert [d.throw_index for d in diagnoses] == [0, 1]
    assert all(d.decision == "obstacle" for d in diagnoses)
    first = json.loads(lines[0])
    assert {"switch_id", "throw_index", "direction", "t_start_ns", "t_end_ns", "model", "decision", "reason",
            "hypotheses", "joint", "latency_ms"} <= set(first)
    assert {h["mode"] for h in first["hypotheses"]} == {"nominal", "left_bolt", "right_bolt", "missing_bearing", "obstacle",
                                                        "drive_friction"}
    assert next(h for h in first["hypotheses"] if h["mode"] == "right_bolt")["unobservable"] == ["right_bolt_offset"]
    obstacle = next(h for h in diagnoses[0].hypotheses if h.mode == "obstacle")
    assert abs(obstacle.params["obstacle_position"] - 1.1) < 0.01


def test_diagnose_on_a_truncated_recording_reports_the_damage_in_one_line(tmp_path):
    damaged = tmp_path / "cut.mcap"
    data = (RECORDINGS / "nominal.mcap").read_bytes()
    damaged.write_bytes(data[: len(data) // 3])
    result = subprocess.run([sys.executable, "-m", "railswitch", "diagnose", str(damaged), "--jsonl"],
                            capture_output=True, text=True, timeout=600)
    assert "Traceback" not in result.stderr
    assert "truncated" in result.stderr and "recovered" in result.stderr
    assert len(result.stderr.strip().splitlines()) == 1


def test_missing_bearing_of_the_paper_is_estimated_within_its_standard_deviation(diagnoser):
    """5000 N·s/m is not among the port's calibration points (2000, 3500, 8000). The paper's switch is new
    (never commissioned), so it is judged against the population: its chairs could be drier than nominal,
    which looks like bearing friction, and the standard deviation says so (about 18 %); still within 10 %
    (the calibration's weather change was one-sided and biased it to 11 % low). Once a switch is commissioned
    the estimate is tighter: tests/integration/test_real_switches.py."""
    diagnoses = diagnose(diagnoser, load_recording(RECORDINGS / "missing_bearing.mcap").messages)
    estimate = diagnoses[-1].estimate
    assert abs(estimate.params["bearing_friction"] - 5000.0) < 2 * estimate.std["bearing_friction"], estimate
    assert abs(estimate.params["bearing_friction"] - 5000.0) / 5000.0 < 0.10, estimate  # 2.8 % now


def test_shipped_bearing_port_is_what_calibration_on_the_plant_gives(plant):
    from railswitch.models.reduced.hybrid import NEUTRAL_PORT
    from railswitch.services.adapters import model_store
    from railswitch.services.core.calibration import bearing_port

    fresh = bearing_port(Diagnoser("poly", port=NEUTRAL_PORT), plant)
    shipped = model_store.load("poly").bearing_port
    for direction in ("left_to_right", "right_to_left"):
        assert fresh[direction]["gain"] == pytest.approx(shipped[direction]["gain"], rel=1e-3)
        assert fresh[direction]["offset_s_m"] == pytest.approx(shipped[direction]["offset_s_m"], abs=5.0)
        assert 0.9 < shipped[direction]["gain"] < 1.0  # distributed friction acts at the drive point a little weaker


def test_calibration_check_fails_a_model_that_misfits_healthy_switches(diagnoser, plant):
    """Step 4 of `railswitch calibrate` (services/core/calibration.py healthy_check): held-out healthy switches
    diagnosed from their first throw. The shipped poly raises no alarm on two of them; the same model with its rail's
    force 10 % off (a rail that fits its training series but not the switches, as a retrained model may) raises
    alarms and never commissions: the check fails."""
    from railswitch.models.diagnosis.estimation import MODEL_RATE_HZ, ThrowEstimator
    from railswitch.models.reduced.hybrid import ReducedParams, ReducedSwitch, port_pairs
    from railswitch.models.diagnosis.switch_diagnoser import ErrorModel, SwitchDiagnoser, population
    from railswitch.services.adapters import model_store
    from railswitch.services.core.calibration import healthy_check

    shipped = healthy_check(diagnoser.switch, plant, switches=2, throws=12)
    assert shipped["passed"] and shipped["false_alarms"] == 0, shipped
    stored = model_store.load("poly")
    off = ReducedSwitch(stored.representation, 1.1 * stored.weights,
                        ReducedParams(bearing_port=port_pairs(stored.bearing_port)), rate_hz=MODEL_RATE_HZ)
    estimator = ThrowEstimator(off)  # CasADi's virtual machine: no machine code for a model used once
    prior, errors = population(stored.healthy_gains, stored.model_weight), ErrorModel(**stored.error_model)
    misfit = healthy_check(lambda _: SwitchDiagnoser(estimator, prior, errors), plant, switches=2, throws=12)
    assert not misfit["passed"] and misfit["false_alarms"] > 0, misfit
