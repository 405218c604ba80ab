"""The paper's estimator, to compare with: each hypothesis's parameters by differential evolution.

Matei et al. pick each fault mode's parameters by differential evolution over thousands of
simulations of the reduced model. `PaperEstimator` does that on the same compiled reduced model,
the same throws, hypotheses, bounds and priors as the project's estimator; only the search differs.
It evaluates each generation in one batched call of the mapped model (the same evaluator that scores
our grid starts), which is the fastest way to run it here, so the comparison is not made against a
handicapped baseline. Settings (SETTINGS): scipy's defaults (population 15 per parameter, tolerance
0.01 of the population's mean objective, mutation 0.5 to 1, recombination 0.7, Latin hypercube start)
and no gradient polish at the end (that would be our method's local search). The standard deviations
at its optimum are computed as ours are (the Laplace covariance there), so the decisions downstream are
made the same way.
"""
from __future__ import annotations

import copy

import numpy as np
from scipy.optimize import differential_evolution

from railswitch.models.diagnosis.estimation import Estimate, HypothesisSpec, Prior, ThrowEstimator
from railswitch.models.reduced.hybrid import PARAMETERS

SETTINGS = {"popsize": 15, "tol": 0.01, "mutation": (0.5, 1.0), "recombination": 0.7, "init": "latinhypercube",
            "maxiter": 1000, "polish": False, "updating": "deferred", "vectorized": True}


class PaperEstimator(ThrowEstimator):
    """ThrowEstimator whose fits are differential evolution over the free parameters (same compiled model)."""

    def __init__(self, estimator: ThrowEstimator, seed: int = 1):
        self.__dict__.update(estimator.__dict__)  # the same compiled functions and buffers
        self.seed = seed
        self.evaluations = 0

    def fit(self, spec: HypothesisSpec, throw, start: dict[str, float] | None = None, iterations: int = 20,
            rival: float = np.inf, prior_weight: float = 0.0, beaten: float = np.inf, slopes=None,
            keep_slopes: bool = False, linearised=None) -> Estimate:
        """The hypothesis's global minimum by differential evolution (start, rival, beaten, the slopes and the start's
        linearisation unused: it needs no start and no Jacobian, and the paper fits every hypothesis to its end)."""
        if not spec.free:
            return super().fit(spec, throw, prior_weight=prior_weight)
        free = list(spec.free)
        low, high = spec.bounds()
        theta = self.reduced.vector(spec.fixed)
        index = [PARAMETERS.index(n) for n in free]
        prior = Prior.of(spec, prior_weight)

        def objective(z: np.ndarray) -> np.ndarray:  # z: free parameters x candidates
            thetas = np.repeat(theta[:, None], z.shape[1], axis=1)
            thetas[index, :] = z
            self.evaluations += z.shape[1]
            return self.objectives(thetas, throw, prior, index)

        result = differential_evolution(objective, list(zip(low, high)), seed=self.seed, **SETTINGS)
        # The Laplace standard deviations at its optimum, as ours are computed (no step taken).
        return super().fit(spec, throw, dict(zip(free, result.x)), iterations=0, prior_weight=prior_weight)


def paper_twin(switch, estimator: PaperEstimator):
    """A copy of a commissioned SwitchDiagnoser (baseline, evidence, health) that fits with `estimator`."""
    twin = copy.deepcopy(switch, memo={id(switch.estimator): estimator, id(switch.prior): switch.prior})
    return twin
