"""The least-squares solver of training and estimation (models/least_squares.py)."""
import numpy as np

from railswitch.models.least_squares import levenberg_marquardt


def _linear_problem(seed: int = 3):
    rng = np.random.default_rng(seed)
    a, b = rng.normal(size=(40, 3)), rng.normal(size=40)
    calls = {"linearise": 0, "cost": 0}

    def linearise(z):
        calls["linearise"] += 1
        return a @ z - b, a

    def cost(z):
        calls["cost"] += 1
        r = a @ z - b
        return float(r @ r)

    return np.linalg.lstsq(a, b, rcond=None)[0], linearise, cost, calls


def test_a_fit_reaches_the_least_squares_solution_from_afar():
    best, linearise, cost, _ = _linear_problem()
    solution = levenberg_marquardt(linearise, best + 5.0, cost=cost, tolerance=1e-10)
    np.testing.assert_allclose(solution.z, best, atol=1e-6)


def test_a_fit_started_at_its_minimum_spends_no_rollout_on_a_step():
    """Converged is known from the linearisation at the start: the step it predicts lowers r'r by less than the
    tolerance, so no trial point is evaluated and no second Jacobian made (the estimator's warm starts)."""
    best, linearise, cost, calls = _linear_problem()
    solution = levenberg_marquardt(linearise, best, cost=cost)
    assert calls == {"linearise": 1, "cost": 0}
    np.testing.assert_array_equal(solution.z, best)


def test_a_fit_a_little_off_its_minimum_takes_one_step_and_stops():
    best, linearise, cost, calls = _linear_problem()
    levenberg_marquardt(linearise, best + 0.1, cost=cost)
    assert calls == {"linearise": 2, "cost": 1}  # start, the step's trial, the Jacobian there; nothing after
