"""The least-squares solver of training and estimation (models/numerics/least_squares.py)."""
import numpy as np

from railswitch.models.numerics.least_squares import levenberg_marquardt


def _linear_problem(seed: int = 3):
    rng = np.random.default_rng(seed)
    a, b = rng.normal(size=(40, 3)), rng.normal(size=40)
    calls = {"linearise": 0, "cost": 0, "residual": 0}

    def linearise(z):
        calls["linearise"] += 1
        return a @ z - b, a

    def cost(z):
        calls["cost"] += 1
        r = a @ z - b
        return float(r @ r)

    def residual(z):
        calls["residual"] += 1
        return a @ z - b

    return np.linalg.lstsq(a, b, rcond=None)[0], linearise, cost, calls, residual


def test_a_fit_reaches_the_least_squares_solution_from_afar():
    best, linearise, cost, _, _ = _linear_problem()
    solution = levenberg_marquardt(linearise, best + 5.0, cost=cost, tolerance=1e-10)
    np.testing.assert_allclose(solution.z, best, atol=1e-6)


def test_a_fit_started_at_its_minimum_spends_no_rollout_on_a_step():
    """Converged is known from the linearisation at the start: the step it predicts lowers r'r by less than the
    tolerance, so no trial point is evaluated and no second Jacobian made (the estimator's warm starts)."""
    best, linearise, cost, calls, _ = _linear_problem()
    solution = levenberg_marquardt(linearise, best, cost=cost)
    assert calls == {"linearise": 1, "cost": 0, "residual": 0}
    np.testing.assert_array_equal(solution.z, best)


def test_a_fit_a_little_off_its_minimum_takes_one_step_and_stops():
    best, linearise, cost, calls, _ = _linear_problem()
    levenberg_marquardt(linearise, best + 0.1, cost=cost)
    assert calls == {"linearise": 2, "cost": 1, "residual": 0}  # start, the step's trial, the Jacobian there; nothing after


def _curved_problem():
    """A residual whose Jacobian changes from point to point (exponential decays): Broyden's update of it is
    exact only along the step taken."""
    t = np.linspace(0.0, 3.0, 30)
    truth = np.array([2.0, 0.7])
    data = truth[0] * np.exp(-truth[1] * t)
    calls = {"linearise": 0, "residual": 0}

    def residual(z):
        calls["residual"] += 1
        return z[0] * np.exp(-z[1] * t) - data + 1e-3 * np.cos(7.0 * t)  # a little misfit: r'r stays above 0

    def linearise(z):
        calls["linearise"] += 1
        calls["residual"] -= 1
        return residual(z), np.column_stack([np.exp(-z[1] * t), -z[0] * t * np.exp(-z[1] * t)])

    return truth, residual, linearise, calls


def test_with_the_residual_alone_a_fit_ends_without_a_jacobian_at_its_last_point():
    """Near the minimum one exact Jacobian (at the start) serves: the accepted step's Broyden update predicts
    no visible decrease, so no second one is made."""
    best, linearise, cost, calls, residual = _linear_problem()
    solution = levenberg_marquardt(linearise, best + 0.1, residual=residual)
    assert calls == {"linearise": 1, "cost": 0, "residual": 1}
    np.testing.assert_array_equal(solution.z, levenberg_marquardt(linearise, best + 0.1, cost=cost).z)  # same step
    np.testing.assert_allclose(solution.jacobian, linearise(best)[1], atol=1e-12)  # a linear residual's, exactly


def test_with_the_residual_alone_a_curved_fit_takes_the_same_steps_to_the_same_minimum():
    """The update only decides whether the fit has converged: every step is taken from an exact Jacobian, so
    the fit visits the points the exact one does and ends at its minimum, with fewer Jacobians."""
    _, residual, linearise, calls = _curved_problem()
    start = np.array([1.0, 1.5])
    exact = levenberg_marquardt(linearise, start, cost=lambda z: float(residual(z) @ residual(z)), tolerance=1e-12)
    exact_jacobians = calls["linearise"]
    calls.update(linearise=0, residual=0)
    updated = levenberg_marquardt(linearise, start, residual=residual, tolerance=1e-12)
    assert updated.history == exact.history[:len(updated.history)]
    np.testing.assert_allclose(updated.z, exact.z, rtol=1e-6)
    assert calls["linearise"] < exact_jacobians


def test_the_updated_jacobian_is_exact_along_the_step_taken():
    _, residual, linearise, _ = _curved_problem()
    start = np.array([1.0, 1.5])
    one = levenberg_marquardt(linearise, start, residual=residual, iterations=1)
    np.testing.assert_allclose(one.jacobian @ (one.z - start), residual(one.z) - residual(start), atol=1e-12)
    assert not np.allclose(linearise(start)[1] @ (one.z - start), residual(one.z) - residual(start), atol=1e-3)


def test_a_step_the_bounds_cut_short_is_damped_not_taken_for_convergence():
    """Two parameters that trade along a narrow valley: the Gauss-Newton step moves both far, the bounds cut the
    first short, and the cut step promises an increase. That ended the fit at its start (a large obstacle's fit
    stopped at its grid point, 34 % low); a damped step goes on to the bounded minimum."""
    from scipy.optimize import lsq_linear

    a = np.array([[1.0, 0.99], [0.0, 0.05], [0.05, 0.0]])
    b = np.array([0.0, -1.0, 1.0])
    low, high = np.array([-1.0, -30.0]), np.array([0.5, 30.0])

    def residual(z):
        return a @ z - b

    best = lsq_linear(a, b, bounds=(low, high), tol=1e-12).x
    for kind in ({"residual": residual}, {"cost": lambda z: float(residual(z) @ residual(z))}):
        solution = levenberg_marquardt(lambda z: (residual(z), a), np.zeros(2), lower=low, upper=high,
                                       tolerance=1e-10, iterations=200, **kind)
        np.testing.assert_allclose(solution.z, best, atol=1e-4)


def test_what_a_linear_fit_is_promised_is_what_its_minimum_lowers_it_by_and_a_hopeless_fit_stops_at_its_start():
    """`hopeless` is asked, where an exact Jacobian has just been made, with r'r and the most the linearised
    residual promises; on a linear residual that promise is exact: r'r at the start less r'r at the minimum. A fit
    it calls hopeless stops there: no trial point, no second Jacobian."""
    best, linearise, _, calls, residual = _linear_problem()
    start = best + np.array([0.3, -0.2, 0.5])
    asked = []

    def hopeless(value, promised):
        asked.append((value, promised))
        return False

    r0, r1 = residual(start), residual(best)
    levenberg_marquardt(linearise, start, residual=residual, hopeless=hopeless)
    np.testing.assert_allclose(asked[0], (r0 @ r0, r0 @ r0 - r1 @ r1), rtol=1e-8)
    calls.update(linearise=0, residual=0)
    solution = levenberg_marquardt(linearise, start, residual=residual, hopeless=lambda value, promised: True)
    assert calls == {"linearise": 1, "cost": 0, "residual": 0}
    np.testing.assert_array_equal(solution.z, start)


def test_a_fit_that_can_still_win_is_not_hopeless():
    """The same fit judged against a cost its promise reaches runs to the minimum, as without the judge."""
    best, linearise, _, _, residual = _linear_problem()
    start = best + np.array([0.3, -0.2, 0.5])
    r1 = residual(best)
    judged = levenberg_marquardt(linearise, start, residual=residual,
                                 hopeless=lambda value, promised: value - promised > r1 @ r1 * (1 + 1e-9))
    plain = levenberg_marquardt(linearise, start, residual=residual)
    np.testing.assert_array_equal(judged.z, plain.z)


def test_a_fit_with_borrowed_slopes_steps_without_a_jacobian_and_ends_where_the_exact_one_does():
    """Slopes of the same model from a point nearby (a previous throw's fit) take the first step: the start costs a
    residual, not a Jacobian, and the fit ends at the same minimum with one Jacobian fewer."""
    _, residual, linearise, calls = _curved_problem()
    for start in (np.array([1.9, 0.72]), np.array([2.05, 0.69])):
        calls.update(linearise=0, residual=0)
        exact = levenberg_marquardt(linearise, start, residual=residual, tolerance=1e-6)
        assert calls["linearise"] == exact.linearised
        nearby = linearise(np.array([1.95, 0.69]))[1]
        calls.update(linearise=0, residual=0)
        borrowed = levenberg_marquardt(linearise, start, residual=residual, tolerance=1e-6, jacobian=nearby)
        assert calls["linearise"] == borrowed.linearised == exact.linearised - 1
        np.testing.assert_allclose(borrowed.cost, exact.cost, rtol=1e-8)
        np.testing.assert_allclose(borrowed.z, exact.z, rtol=1e-6)


def test_borrowed_slopes_that_do_not_take_a_step_give_way_to_the_exact_ones_at_the_start():
    """Slopes pointing the wrong way (another model's) cost one trial residual; the fit then computes the
    Jacobian at its start and goes on as without them, to the same minimum in as many iterations."""
    _, residual, linearise, calls = _curved_problem()
    start = np.array([1.0, 1.5])
    exact = levenberg_marquardt(linearise, start, residual=residual, tolerance=1e-12)
    calls.update(linearise=0, residual=0)
    wrong = -linearise(start)[1]
    borrowed = levenberg_marquardt(linearise, start, residual=residual, tolerance=1e-12, jacobian=wrong)
    assert borrowed.history == exact.history and borrowed.iterations == exact.iterations
    np.testing.assert_array_equal(borrowed.z, exact.z)
    assert borrowed.linearised == exact.linearised


def test_the_same_on_every_processor_algebra_agrees_with_blas_to_its_rounding():
    """Its a'a splits each column into two integers of b bits and drops the low parts' product: each row's product
    off by 2^-2b of the columns' largest entries (b = 19 for 15 000 rows: 4e-12), 2.3e-11 of the columns' norms here;
    its sums and its Cholesky solve round as BLAS's do."""
    from railswitch.models.numerics.least_squares import SAME_ON_EVERY_PROCESSOR as algebra

    rng = np.random.default_rng(5)
    a = rng.normal(size=(15_000, 30)) * np.logspace(-3, 3, 30)  # columns of six decades
    r = rng.normal(size=15_000)
    gram = algebra.gram(a)
    norms = np.sqrt(np.diag(a.T @ a))
    assert np.max(np.abs(gram - a.T @ a) / np.outer(norms, norms)) < 1e-10
    np.testing.assert_allclose(algebra.gradient(a, r), a.T @ r, rtol=1e-12, atol=1e-12 * np.max(np.abs(a.T @ r)))
    damped = gram + 1e-3 * np.diag(np.diag(gram))
    np.testing.assert_allclose(algebra.solve(damped, a.T @ r), np.linalg.solve(damped, a.T @ r), rtol=1e-9)


def test_a_fit_in_the_same_on_every_processor_algebra_reaches_the_least_squares_solution():
    from railswitch.models.numerics.least_squares import SAME_ON_EVERY_PROCESSOR

    best, linearise, cost, _, _ = _linear_problem()
    solution = levenberg_marquardt(linearise, best + 5.0, cost=cost, tolerance=1e-10, algebra=SAME_ON_EVERY_PROCESSOR)
    np.testing.assert_allclose(solution.z, best, atol=1e-6)
