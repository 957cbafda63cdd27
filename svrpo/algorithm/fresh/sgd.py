"""Fresh mini-batch SGD: the fresh-sample estimators' ablation without a control variate."""

from __future__ import annotations

import torch

from svrpo.algorithm.fresh.base import FreshEstimator
from svrpo.algorithm.fresh.gradients import FreshGradients


class FreshMinibatchGradient(FreshEstimator):
    """v_j = mean_B grad l_t(w_j) on the fresh steps (unbiased; the full variance of B steps)."""

    path_dependent = False

    def combine(self, fresh: FreshGradients) -> torch.Tensor:
        return fresh.at_current()
