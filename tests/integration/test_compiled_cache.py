"""Compiled CasADi Functions cached on disk: compiled once, loaded by later calls, same numbers."""
import shutil

import casadi as ca
import numpy as np
import pytest

from railswitch.models.diagnosis.estimation import MODEL_RATE_HZ, Measurement, ThrowEstimator
from railswitch.models.reduced.hybrid import ReducedSwitch
from railswitch.models.plant.reference import throw_reference
from railswitch.models.plant.signals import MotorSignals
from railswitch.services.adapters import model_store
from railswitch.services.adapters.compiled import MachineCode, jit_compiled_all

needs_compiler = pytest.mark.skipif(shutil.which("gcc") is None and shutil.which("cc") is None,
                                    reason="no C compiler: nothing is cached")


def small_function() -> ca.Function:
    """Two inputs, a dense and a sparse (Jacobian) output, as the estimator's Functions have."""
    x, a = ca.MX.sym("x", 3), ca.MX.sym("a", 2)
    y = ca.vertcat(ca.sin(x[0]) * a[0], x[1] * x[2] + a[1], ca.exp(-x[2]))
    return ca.Function("small", [x, a], [y, ca.jacobian(y, x)], ["x", "a"], ["y", "dy_dx"])


@needs_compiler
def test_first_call_compiles_one_library_and_the_second_loads_it_with_the_same_numbers(tmp_path):
    function = small_function()
    x, a = np.array([0.3, -1.2, 0.7]), np.array([2.0, 0.5])
    (first,), compiled = jit_compiled_all([function], tmp_path)
    libraries = sorted(tmp_path.iterdir())
    assert compiled and [p.suffix for p in libraries] == [".so"]
    stamp = libraries[0].stat().st_mtime_ns
    (second,), compiled = jit_compiled_all([function], tmp_path)
    assert compiled and sorted(tmp_path.iterdir()) == libraries and libraries[0].stat().st_mtime_ns == stamp
    for loaded in (first, second):
        assert loaded.class_name() == "External"  # the cached library, not CasADi's JIT
        assert loaded.name_in() == ["x", "a"] and loaded.name_out() == ["y", "dy_dx"]
        assert loaded.sparsity_out(1) == function.sparsity_out(1)
        for got, expected in zip(loaded(x, a), function(x, a)):
            np.testing.assert_allclose(np.asarray(got), np.asarray(expected), rtol=1e-14, atol=0.0)


def test_a_missing_cache_directory_is_not_created_and_the_function_still_evaluates(tmp_path):
    function = small_function()
    (compiled_function,), _ = jit_compiled_all([function], tmp_path / "missing")
    got = compiled_function(np.array([0.3, -1.2, 0.7]), np.array([2.0, 0.5]))[0]
    np.testing.assert_allclose(np.asarray(got), np.asarray(function([0.3, -1.2, 0.7], [2.0, 0.5])[0]), rtol=1e-14)
    assert not (tmp_path / "missing").exists()


@needs_compiler
def test_estimator_built_from_the_cache_gives_the_uncompiled_residual_and_derivatives(tmp_path):
    stored = model_store.load("poly")
    reduced = ReducedSwitch(stored.representation, stored.weights, rate_hz=MODEL_RATE_HZ)
    reference, t_s = throw_reference("left_to_right"), np.arange(1, 151) / 50.0  # 3 s: two compiled chunks
    uncompiled = ThrowEstimator(reduced)
    blank = np.zeros(len(t_s))
    y = uncompiled.simulate(Measurement("left_to_right", reference, t_s, MotorSignals(blank, blank, blank), 0.0, 1.0),
                            {"left_bolt_offset": 0.05})
    m = Measurement("left_to_right", reference, t_s, MotorSignals(y["current_a"], y["angle_rad"], y["velocity_rad_s"]),
                    0.0, 1.0)
    theta = reduced.vector({"left_bolt_offset": 0.02, "bearing_friction": 1e3})
    free = [[0], [0, 2, 5, 6, 7], [0, 1, 2, 3, 4, 5, 6], list(range(9))]

    def evaluations(estimator: ThrowEstimator) -> list:
        """Every compiled Function: the chunk (residual), the batched chunks of each capacity at both rates, each
        sensitivity chunk."""
        throw = estimator.prepare(m)
        out = [estimator.residuals(theta, throw)]
        for count in (3, 30):  # the smaller and the larger mapped call at each rate
            out += [estimator.costs(np.tile(theta[:, None], count), throw),
                    estimator.costs(np.tile(theta[:, None], count), throw, coarse=True)]
        for index in free:
            out += estimator.linearise(theta, throw, index)
        return [np.asarray(value) for value in out]

    expected = evaluations(uncompiled)
    for build in ("compiles", "loads"):
        cached = ThrowEstimator(reduced, MachineCode(tmp_path))
        functions = 1 + len(cached.MODEL_CAPACITIES) + len(cached.CAPACITIES) + len(cached.directions)
        assert cached._chunk.function.class_name() == "External" and len(list(tmp_path.glob("*.so"))) == functions, build
        for got, value in zip(evaluations(cached), expected):
            np.testing.assert_allclose(got, value, rtol=1e-10, atol=1e-12 * np.max(np.abs(value)))


@needs_compiler
def test_exact_machine_code_gives_the_plants_numbers_to_the_bit(tmp_path, monkeypatch):
    """Training's data come from the plant in MachineCode(exact=True): its long fits end elsewhere when a rounding per
    operation moves (with the default flags' plant, a retrained causal rail drifted 40 mm on one validation series).
    Exact machine code gives the interpreted plant's throw to the bit; the default one does not."""
    from railswitch.models.plant.high_fidelity import Plant
    from railswitch.models.plant.simulation import SwitchSimulation
    from railswitch.services.adapters.compiled import compiled_plant

    def two_throws(plant: Plant) -> tuple[np.ndarray, np.ndarray]:  # the package's tests do not import benchmarks
        sim = SwitchSimulation(plant)
        throws = [sim.throw() for _ in range(2)]
        return (np.concatenate([t.samples.rail_position_m for t in throws]),
                np.concatenate([t.samples.signals.current_a for t in throws]))

    monkeypatch.setenv("RAILSWITCH_CACHE", str(tmp_path))
    rails, currents = two_throws(Plant())
    exact_rails, exact_currents = two_throws(compiled_plant(exact=True))
    fast_rails, _ = two_throws(compiled_plant())
    np.testing.assert_array_equal(exact_rails, rails)
    np.testing.assert_array_equal(exact_currents, currents)
    np.testing.assert_allclose(fast_rails, rails, rtol=0, atol=1e-6)  # within CVODES' tolerances
    assert not np.array_equal(fast_rails, rails)
