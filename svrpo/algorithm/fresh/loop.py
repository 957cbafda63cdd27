"""Kept for one name that tests/test_fresh.py imports: the fresh-sample steps now run in the one
inner loop (svrpo.algorithm.update.update_policy, with svrpo.algorithm.step_rows.FreshDraws), and their
evaluator is FullBatchEvaluator given the snapshot rows' evaluator."""

from svrpo.algorithm.objectives import SurrogateBatch
from svrpo.algorithm.update import FullBatchEvaluator
from svrpo.config import Surrogate
from svrpo.models.policy import GaussianMlpPolicy


class FreshBatchEvaluator(FullBatchEvaluator):
    """FullBatchEvaluator on rows drawn in the loop, with the snapshot rows' evaluator (and its
    KL convention)."""

    def __init__(self, policy: GaussianMlpPolicy, batch: SurrogateBatch, kind: Surrogate,
                 snapshot: FullBatchEvaluator) -> None:
        super().__init__(policy, batch, kind, snapshot.kl_per_action_dimension, snapshot)
