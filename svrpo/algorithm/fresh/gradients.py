"""Gradients of l_t(w) = log pi_w(a_t|s_t) A_t on a batch of fresh steps, at any point.

A fresh batch is drawn with the inner iterate w_j (the behaviour policy). Its SurrogateBatch
keeps the behaviour policy's log pi_{w_j}(a_t|s_t) in `old_log_prob` (the denominator of every
importance ratio, and of the ratio surrogate the line search reads) and the sampling policy
pi_{w~}'s means in `old_mean` / `old_log_std` (the anchor of the iteration's KL budget): so the
trust-region parts read a fresh batch exactly as they read the snapshot batch.

Weights are per decision: omega_t = pi_{w'}(a_t|s_t) / pi_{w_j}(a_t|s_t) for the step's own
state-action pair, not the product over the trajectory up to t (Papini et al.'s trajectory
weights multiply up to 1,000 ratios on these horizons and have a variance that grows with them).
With advantages from a critic, l_t is the per-decision form of the policy gradient whose
expectation under pi_{w'} the weights recover exactly when the states' distribution is the same
(a one-step task, where both forms coincide) and approximately otherwise, as in TRPO's surrogate.
"""

from __future__ import annotations

import copy

import torch

from svrpo.algorithm.objectives import SurrogateBatch
from svrpo.models.parameters import flat_gradient, flat_parameters, set_flat_parameters
from svrpo.models.policy import MlpPolicy


def importance_weights(log_prob: torch.Tensor, behaviour_log_prob: torch.Tensor,
                       clip: float | None) -> torch.Tensor:
    """omega_t = pi_{w'}(a_t|s_t) / pi_{w_j}(a_t|s_t) = exp(log_prob - behaviour_log_prob), each
    truncated at `clip` (None: not truncated). No graph: the weights are constants."""
    weights = torch.exp(log_prob.detach() - behaviour_log_prob)
    return weights if clip is None else torch.clamp(weights, max=clip)


def weighted_score_gradient(policy: MlpPolicy, batch: SurrogateBatch,
                            clip: float | None) -> torch.Tensor:
    """mean_t omega_t A_t grad log pi_w(a_t|s_t) at the policy's parameters w, omega_t the
    (truncated) weight of w against the behaviour policy: the importance-sampled estimate of
    grad L(w) from steps drawn with w_j (untruncated, it is grad of mean_t pi_w / pi_{w_j} A_t)."""
    log_prob = policy.log_prob(batch.observations, batch.actions)
    weights = importance_weights(log_prob, batch.old_log_prob, clip)
    return flat_gradient((weights * batch.advantages * log_prob).mean(), policy)


def score_gradient(policy: MlpPolicy, batch: SurrogateBatch) -> torch.Tensor:
    """mean_t A_t grad log pi_w(a_t|s_t) at the policy's parameters: grad L_B(w_j) on steps
    drawn with w_j itself (every weight is 1)."""
    log_prob = policy.log_prob(batch.observations, batch.actions)
    return flat_gradient((batch.advantages * log_prob).mean(), policy)


class FreshGradients:
    """The gradients one inner step of a fresh-sample estimator needs, on its fresh batch:
    at the live iterate w_j (`at_current`, weights 1) and importance-weighted at any other flat
    parameter vector (`at`: w~ for SVRPG, w_{j-1} for SRVR-PG and STORM-PG)."""

    def __init__(self, policy: MlpPolicy, batch: SurrogateBatch, clip: float | None,
                 scratch: MlpPolicy | None = None) -> None:
        self.policy = policy
        """The live policy (its parameters are w_j, the behaviour policy of `batch`)."""
        self.batch = batch
        self.clip = clip
        self._scratch = scratch if scratch is not None else copy.deepcopy(policy)

    def current_point(self) -> torch.Tensor:
        """w_j as a flat copy."""
        return flat_parameters(self.policy)

    def at_current(self) -> torch.Tensor:
        """mean_B grad l_t(w_j)."""
        return score_gradient(self.policy, self.batch)

    def weights_at(self, point: torch.Tensor) -> torch.Tensor:
        """omega_t of the flat parameters `point` against w_j, truncated as the estimate uses them."""
        set_flat_parameters(self._scratch, point)
        with torch.no_grad():
            log_prob = self._scratch.log_prob(self.batch.observations, self.batch.actions)
        return importance_weights(log_prob, self.batch.old_log_prob, self.clip)

    def at(self, point: torch.Tensor) -> torch.Tensor:
        """mean_B omega_t grad l_t(point), omega_t = pi_point / pi_{w_j} (truncated at clip)."""
        set_flat_parameters(self._scratch, point)
        return weighted_score_gradient(self._scratch, self.batch, self.clip)
