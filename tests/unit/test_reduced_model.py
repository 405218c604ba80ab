"""Reduced hybrid switch models: dissipation, fidelity to the plant, fault sensitivities, training."""
import casadi as ca
import numpy as np
import pytest

from railswitch.services.adapters import model_store
from railswitch.models.reduced.hybrid import PARAMETERS
from railswitch.models.reduced.rail_models import REPRESENTATIONS
from railswitch.models.reduced.hybrid import OUTPUTS, ReducedParams, ReducedSwitch
from railswitch.models.plant.simulation import SwitchSimulation
from railswitch.schemas import RAIL_MODELS

MODELS = RAIL_MODELS  # every representation


@pytest.fixture(scope="module")
def nominal_plant_throws(plant):
    sim = SwitchSimulation(plant)
    starts, throws = [], []
    for _ in range(2):
        starts.append(plant.signals_at(sim.state))
        throws.append(sim.throw())
    return starts, throws


@pytest.mark.parametrize("name", ["poly", "nn"])
def test_acausal_representation_energy_never_increases_without_force(name):
    representation, weights = model_store.load(name).representation, model_store.load(name).weights
    x, v = ca.SX.sym("x"), ca.SX.sym("v")
    rhs = ca.vertcat(v, representation.acceleration(x, v, 0.0, weights))
    grid = np.linspace(0.002, 2.0, 1000)
    integrate = ca.integrator("free_rail", "cvodes", {"x": ca.vertcat(x, v), "ode": rhs}, 0.0, grid,
                              {"reltol": 1e-10, "abstol": 1e-12})
    energy = ca.Function("energy", [x, v], [representation.energy(x, v, weights, quadrature_points=512)])
    rng = np.random.default_rng(11)
    for _ in range(8):
        s0 = np.array([rng.uniform(0.95, 1.25), rng.uniform(-0.3, 0.3)])
        trajectory = np.hstack([s0[:, None], np.asarray(integrate(x0=s0)["xf"])])
        e = np.array([float(energy(*p)) for p in trajectory.T])
        assert e[0] > 0.5
        assert np.all(np.diff(e) <= 1e-7 * e[0])
        assert e[-1] < e[0]


@pytest.mark.parametrize("name", MODELS)
def test_shipped_weights_reproduce_the_plants_nominal_throws(name, nominal_plant_throws):
    representation, weights = model_store.load(name).representation, model_store.load(name).weights
    reduced = ReducedSwitch(representation, weights)
    starts, throws = nominal_plant_throws
    for start, throw in zip(starts, throws):
        s0 = reduced.initial_state(start["rail_position_m"], start["angle_rad"], start["velocity_rad_s"],
                                   start["current_a"])
        out = reduced.simulate(s0, throw.reference, len(throw.samples))
        assert abs(out["rail_position_m"][-1] - throw.samples.rail_position_m[-1]) < 0.005
        plateau = slice(150, 250)  # 3 s to 5 s: the blades are moving
        plant_plateau = np.mean(np.abs(throw.samples.signals.current_a[plateau]))
        assert np.mean(np.abs(out["current_a"][plateau])) == pytest.approx(plant_plateau, rel=0.10)


def output_sensitivities(reduced, s0, reference, faults):
    """d(current, velocity)/d(fault parameter) over a throw, by CasADi's AD."""
    n = 350
    theta = ca.MX.sym("theta", len(PARAMETERS))
    y, _ = reduced.rollout(n)(s0, reduced.reference_columns(reference, n), theta, reduced.weights)
    signals = ca.vertcat(y[OUTPUTS.index("current_a"), :].T, y[OUTPUTS.index("velocity_rad_s"), :].T)
    jac = ca.Function("fault_jacobian", [theta], [ca.jacobian(signals, theta)])
    return dict(zip(PARAMETERS, np.asarray(jac(reduced.vector(faults))).T))


@pytest.mark.parametrize("name", MODELS)
def test_outputs_have_finite_nonzero_derivatives_where_each_fault_acts(name):
    from railswitch.models.plant.reference import throw_reference

    representation, weights = model_store.load(name).representation, model_store.load(name).weights
    reduced = ReducedSwitch(representation, weights)
    faults = {"left_bolt_offset": 0.01, "right_bolt_offset": 0.01, "bearing_friction": 2000.0,
              "obstacle_friction": 5e4, "obstacle_position": 1.10}
    left_to_right = output_sensitivities(reduced, reduced.initial_state(1.0, 0.0),
                                         throw_reference("left_to_right"), faults)
    closed_right = reduced.initial_state(1.2, reduced.params.plant.drive.throw_angle_rad)
    right_to_left = output_sensitivities(reduced, closed_right, throw_reference("right_to_left"), faults)
    for sensitivities in (left_to_right, right_to_left):
        assert all(np.all(np.isfinite(column)) for column in sensitivities.values())
    assert np.max(np.abs(left_to_right["left_bolt_offset"])) > 1.0
    assert np.max(np.abs(right_to_left["right_bolt_offset"])) > 1.0
    for both in ("bearing_friction", "obstacle_friction", "obstacle_position"):
        assert np.max(np.abs(left_to_right[both])) > 0 and np.max(np.abs(right_to_left[both])) > 0


@pytest.mark.parametrize("name", MODELS)
def test_sensitivity_rollout_gives_the_derivatives_of_the_rollout(name):
    """The estimator's Jacobians (sensitivities carried through each step, the learned rails through their
    features' stand-ins) equal CasADi's AD of the rollout."""
    from railswitch.models.plant.reference import throw_reference

    representation, weights = model_store.load(name).representation, model_store.load(name).weights
    reduced = ReducedSwitch(representation, weights)
    n, s0 = 120, reduced.initial_state(1.0, 0.0)
    refs = reduced.reference_columns(throw_reference("left_to_right"), n)
    theta = reduced.vector({"left_bolt_offset": 0.03, "bearing_friction": 2000.0, "obstacle_friction": 5e4,
                          "obstacle_position": 1.05})
    symbol = ca.MX.sym("theta", len(PARAMETERS))
    y, _ = reduced.rollout(n)(s0, refs, symbol, reduced.weights)
    expected = np.asarray(ca.Function("j", [symbol], [ca.jacobian(ca.vec(y), symbol)])(theta))
    seeds = np.eye(len(PARAMETERS))[:, [0, 2, 4, 5, 9]]  # five of the parameters, faults and own, in any order
    y_sens, y_dot = reduced.sensitivity_rollout(n, seeds.shape[1])(s0, refs, theta, seeds, reduced.weights)
    nominal, _ = reduced.rollout(n)(s0, refs, theta, reduced.weights)
    np.testing.assert_allclose(np.asarray(y_sens), np.asarray(nominal), rtol=1e-12)
    y_dot = np.asarray(y_dot)
    for j, parameter in enumerate([0, 2, 4, 5, 9]):
        block = y_dot[j * len(OUTPUTS):(j + 1) * len(OUTPUTS), :]
        column = expected[:, parameter]
        np.testing.assert_allclose(block.ravel(order="F"), column, rtol=1e-8, atol=1e-9 * np.max(np.abs(column)))


@pytest.mark.parametrize("name", ["nn", "causal"])
def test_features_jacobian_is_the_derivative_of_the_features(name):
    """A representation's features and their Jacobian in (x, v) (what the sensitivities carry the learned rail by,
    StandIns), written out or CasADi's, equal CasADi's derivative of the features at points over the travel, on
    both sides of rest, to the rounding of sums over the hidden units."""
    stored = model_store.load(name)
    x, v, w = ca.SX.sym("x"), ca.SX.sym("v"), ca.DM(stored.weights)
    features = stored.representation.features(x, v, w)
    expected = ca.Function("expected", [x, v], [features, ca.jacobian(features, ca.vertcat(x, v))])
    made = ca.Function("made", [x, v], list(stored.representation.features_jacobian(x, v, w)))
    rng = np.random.default_rng(5)
    for position, velocity in zip(rng.uniform(0.98, 1.22, 200), rng.uniform(-0.4, 0.4, 200)):
        (value, jacobian), (made_value, made_jacobian) = expected(position, velocity), made(position, velocity)
        np.testing.assert_array_equal(np.asarray(made_value), np.asarray(value))
        jacobian = np.asarray(jacobian)
        row_scale = np.max(np.abs(jacobian), axis=1, keepdims=True)
        np.testing.assert_allclose(np.asarray(made_jacobian) / row_scale, jacobian / row_scale, rtol=0, atol=1e-10)


@pytest.mark.parametrize("name", ["nn", "causal"])
def test_kernels_make_the_features_and_the_steps_of_the_networks_written_out(name):
    """A learned rail's kernels (its features as C loops over the hidden units, Representation.kernel_code) give its
    features and their Jacobian, and the diagnosis's steps made with them (a rollout's and one carrying five
    sensitivities) give those made without, at states across the travel, to the rounding of the units' sums."""
    from railswitch.models.reduced.hybrid import kernels
    from railswitch.services.adapters.compiled import MachineCode

    stored = model_store.load(name)
    made = kernels(stored.representation, stored.weights, MachineCode())
    if made is None:
        pytest.skip("no C compiler: the diagnosis writes the network out")
    x, v, w = ca.SX.sym("x"), ca.SX.sym("v"), ca.DM(stored.weights)
    expected = ca.Function("expected", [x, v], list(stored.representation.features_jacobian(x, v, w)))
    rng = np.random.default_rng(11)
    for position, velocity in zip(rng.uniform(0.98, 1.22, 100), rng.uniform(-0.4, 0.4, 100)):
        value, jacobian = (np.asarray(out) for out in expected(position, velocity))
        np.testing.assert_allclose(np.asarray(made[0](position, velocity)), value, rtol=1e-12, atol=1e-12)
        kernel_value, kernel_jacobian = (np.asarray(out) for out in made[1](position, velocity))
        np.testing.assert_allclose(kernel_value, value, rtol=1e-12, atol=1e-12)
        row_scale = np.max(np.abs(jacobian), axis=1, keepdims=True)
        np.testing.assert_allclose(kernel_jacobian.reshape(jacobian.shape, order="F") / row_scale, jacobian / row_scale,
                                   rtol=0, atol=1e-10)
    reduced = ReducedSwitch(stored.representation, stored.weights, rate_hz=100.0)
    pairs = [(reduced.fixed_step(), reduced.fixed_step(made)),
             (reduced.fixed_sensitivity_step(5), reduced.fixed_sensitivity_step(5, made))]
    seeds = np.eye(len(PARAMETERS))[:, [0, 2, 3, 4, 9]].ravel(order="F")
    for _ in range(20):
        state = reduced.initial_state(rng.uniform(1.0, 1.2), rng.uniform(-1.0, 1.0))
        state[[1, 3, 5]] = rng.uniform(-20, 20), rng.uniform(-5, 5), rng.uniform(-0.2, 0.2)
        refs, theta = rng.uniform(-30, 30, 2), reduced.vector({"bearing_friction": 3000.0, "left_bolt_offset": 0.04})
        for (written, kernel), args in zip(pairs, [(state, refs, theta),
                                                   (np.concatenate([state, rng.normal(size=5 * len(state))]), refs,
                                                    theta, seeds)]):
            for a, b in zip(written(*args), kernel(*args)):
                a, b = np.asarray(a), np.asarray(b)
                np.testing.assert_allclose(b, a, rtol=1e-9, atol=1e-9 * np.max(np.abs(a)))


def test_without_kernels_the_diagnosis_writes_the_networks_out():
    """No kernels where the compiler makes none (interpreted, or a Compiler without `kernel`), where the rail has no
    networks (poly), or where the C compiler refuses a kernel's code: the steps then write the networks out."""
    import shutil

    from railswitch.models.reduced.hybrid import kernels
    from railswitch.services.adapters.compiled import MachineCode

    causal, poly = model_store.load("causal"), model_store.load("poly")
    assert kernels(causal.representation, causal.weights, None) is None
    assert kernels(causal.representation, causal.weights, lambda functions: functions) is None
    assert kernels(poly.representation, poly.weights, MachineCode()) is None
    if shutil.which("gcc") is None and shutil.which("cc") is None:
        pytest.skip("no C compiler")
    assert MachineCode().kernel("broken", "  y[0] = ;\n", {"x": 1}, {"y": 1}) is None
    assert float(MachineCode().kernel("twice", "  y[0] = 2.0 * x[0];\n", {"x": 1}, {"y": 1})(3.0)) == 6.0


def test_the_switch_stage_of_training_has_the_jacobian_of_the_rollout_in_the_weights():
    """Training's switch stage: sensitivities over the rail's weights, a block of them per rollout, equal CasADi's
    AD of the rollout (the Jacobian the stage used to build, at ten times the cost)."""
    from railswitch.models.reduced import training
    from railswitch.models.plant.reference import throw_reference

    representation, weights = model_store.load("causal").representation, model_store.load("causal").weights
    reduced = ReducedSwitch(representation, weights)
    n, s0, reference = 80, reduced.initial_state(1.0, 0.0), throw_reference("left_to_right")
    zeros = np.zeros(n)
    stage = training.switch_residuals(reduced, [training.SwitchTarget(s0, reference, zeros, zeros, zeros)])
    r, jacobian = stage.linearise(weights)
    symbol = ca.MX.sym("w", representation.size)
    y, _ = reduced.rollout(n)(s0, reduced.reference_columns(reference, n), reduced.vector(), symbol)
    scaled = ca.vertcat(y[0, :].T / training.CURRENT_RESIDUAL_A, y[3, :].T / training.POSITION_RESIDUAL_M,
                        y[4, :].T / training.VELOCITY_RESIDUAL_M_S)
    expected = ca.Function("j", [symbol], [scaled, ca.jacobian(scaled, symbol)])(weights)
    np.testing.assert_allclose(r, np.asarray(expected[0]).ravel(), rtol=1e-12)
    assert stage.cost(weights) == pytest.approx(float(r @ r), rel=1e-12)
    expected = np.asarray(expected[1])
    np.testing.assert_allclose(jacobian, expected, rtol=1e-8, atol=1e-9 * np.max(np.abs(expected)))


def test_describe_lists_each_reduced_model_with_states_parameters_and_equations():
    from railswitch.services.model_jobs import describe_reduced

    described = describe_reduced()
    assert set(described) == set(MODELS)
    for name, entry in described.items():
        assert entry["parameters"] == REPRESENTATIONS[name].size
        assert entry["switch_states"] == 8 and entry["equations"]
        assert entry["trained"]["series_seeds"]


def test_hook_levels_stay_between_0_and_1_when_a_bolt_arrives_within_a_step():
    """The lock's hooks relax exactly (Rush-Larsen): a hook whose release switches on during a step,
    as the driving bolt arrives, never overshoots out of [0, 1], whatever the step and the speed."""
    from hypothesis import given, settings
    from hypothesis import strategies as st

    from railswitch.models.plant.drive import motor_angle_at_rod

    representation, weights = model_store.load("poly").representation, model_store.load("poly").weights
    reduced = {rate: ReducedSwitch(representation, weights, rate_hz=rate) for rate in (10.0, 50.0)}
    p = reduced[10.0].params.plant
    free_play = p.adjuster.free_play_m

    @settings(max_examples=40, deadline=None, derandomize=True)
    @given(rate=st.sampled_from(sorted(reduced)), speed=st.floats(20.0, 300.0), before_m=st.floats(0.0, 0.004),
           bolt=st.floats(-0.02, 0.2), leftwards=st.booleans())
    def check(rate, speed, before_m, bolt, leftwards):
        if leftwards:  # closed at the right, the right bolt about to reach the adjuster's release point
            rod = p.drive.linkage_ratio * p.rail.right_stock_m - free_play - bolt + before_m
            s = [motor_angle_at_rod(p.drive, rod), -speed, 0.0, 0.0, p.rail.right_stock_m, 0.0, 0.0, 1.0]
        else:
            rod = p.drive.linkage_ratio * p.rail.left_stock_m + free_play + bolt - before_m
            s = [motor_angle_at_rod(p.drive, rod), speed, 0.0, 0.0, p.rail.left_stock_m, 0.0, 1.0, 0.0]
        refs = np.array([s[1], s[1]])
        s_next, _ = reduced[rate].step(np.array(s), refs, reduced[rate].vector({"left_bolt_offset": bolt,
                                                                                "right_bolt_offset": bolt}), weights)
        levels = np.asarray(s_next).ravel()[6:]
        assert np.all((levels >= 0.0) & (levels <= 1.0)), levels

    check()


@pytest.mark.parametrize("name", ["poly", "nn"])
def test_the_shooting_stage_of_training_has_the_jacobian_of_the_rollout_in_z(name):
    """Training's shooting stage carries the segments' derivatives in z through each step (the step's own Jacobian
    and the chain rule): they equal CasADi's AD of the rollout, which the stage used to build at five times the
    cost for nn."""
    from railswitch.models.reduced import training

    representation = REPRESENTATIONS[name]
    rng = np.random.default_rng(4)
    samples = 3 * training.SEGMENT_SAMPLES + 2  # three segments
    t = np.arange(samples) / training.RATE_HZ
    data = [training.RailData(force_n=3000.0 * np.sin(2.0 * t) + rng.normal(0.0, 50.0, samples),
                              position_m=1.1 + 0.05 * np.sin(1.3 * t), velocity_m_s=0.065 * np.cos(1.3 * t),
                              acceleration_m_s2=-0.085 * np.sin(1.3 * t))]
    stage = training.acausal_residuals(representation, ReducedParams(), data)
    z = representation.z_from_weights(representation.initial_weights(0)) + rng.normal(0.0, 0.05, representation.size)
    r, jacobian = stage.linearise(z)
    assert stage.cost(z) == pytest.approx(float(r @ r), rel=1e-12)
    starts, forces, measured = training.shooting_segments(data)
    symbol = ca.MX.sym("z", representation.size)
    roll = training.rail_step_function(representation, ReducedParams()).mapaccum("segment", training.SEGMENT_SAMPLES)
    w = representation.weights_from_z(symbol)
    repeated = ca.repmat(w, 1, training.SEGMENT_SAMPLES)
    predicted = ca.horzcat(*[roll(starts[:, k], forces[:, :, k].reshape(2, -1), repeated)
                             for k in range(starts.shape[1])])
    scale = ca.DM([[1.0 / training.POSITION_RESIDUAL_M], [1.0 / training.VELOCITY_RESIDUAL_M_S]])
    target = measured.transpose(0, 2, 1).reshape(2, -1)
    scaled = ca.vec((predicted - ca.DM(target)) * ca.repmat(scale, 1, predicted.shape[1]))
    expected_r, expected_j = ca.Function("j", [symbol], [scaled, ca.jacobian(scaled, symbol)])(z)
    rows = int(expected_r.shape[0])
    np.testing.assert_allclose(r[:rows], np.asarray(expected_r).ravel(), rtol=1e-12, atol=1e-12)
    expected_j = np.asarray(expected_j)
    np.testing.assert_allclose(jacobian[:rows], expected_j, rtol=1e-8, atol=1e-9 * np.max(np.abs(expected_j)))


def test_the_causal_regression_in_chunks_has_every_samples_residual_and_gradient():
    """The regression evaluates its rows REGRESSION_CHUNK samples a call (the last chunk padded): the same residual
    and Jacobian, row for row, as the one-sample Functions it is made of, on one thread or two."""
    from railswitch.models.reduced import training
    from railswitch.models.reduced.hybrid import stock_rail_force

    representation, reduced = REPRESENTATIONS["causal"], ReducedParams()
    rng = np.random.default_rng(5)
    samples = training.REGRESSION_CHUNK + 77  # a chunk and a padded one
    t = np.arange(samples) / training.RATE_HZ
    data = [training.RailData(force_n=rng.normal(0.0, 2000.0, samples), position_m=1.1 + 0.05 * np.sin(0.7 * t),
                              velocity_m_s=0.035 * np.cos(0.7 * t), acceleration_m_s2=rng.normal(0.0, 0.5, samples))]
    z = representation.initial_weights(1)
    x, v, a, f = (ca.SX.sym(k) for k in "xvaf")
    w = ca.SX.sym("w", representation.size)
    r = (representation.force(x, v, a, w) - f - stock_rail_force(reduced, x, v)) / training.FORCE_SCALE_N
    one = ca.Function("one", [x, v, a, f, w], [r, ca.jacobian(r, w)])
    d = data[0]
    expected = [np.asarray(out)
                for out in one.map(samples)(d.position_m, d.velocity_m_s, d.acceleration_m_s2, d.force_n, z)]
    expected_j = expected[1].reshape(representation.size, -1, order="F").T
    for threads in (1, 2):
        stage = training.causal_regression(representation, reduced, data, threads)
        residual, jacobian = stage.linearise(z)
        np.testing.assert_array_equal(residual[:samples], expected[0].ravel())
        np.testing.assert_array_equal(jacobian[:samples], expected_j)
        assert residual.size == samples + representation.size  # the ridge's rows follow, nothing of the padding
        assert stage.cost(z) == pytest.approx(float(residual @ residual), rel=1e-12)
