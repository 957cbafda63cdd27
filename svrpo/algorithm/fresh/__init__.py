"""Fresh samples in the inner loop: each inner step j >= 1 draws m new steps with the inner
iterate w_j and corrects the snapshot gradient with importance weights (SVRPG, SRVR-PG,
STORM-PG, and their plain fresh-SGD twin), inside the trust region.

* `gradients.py`  the per-decision importance weights and the gradients on one fresh batch;
* `base.py`       what the four estimators share (the part lifecycle, the recorded path);
* `svrpg.py`, `srvrpg.py`, `stormpg.py`, `sgd.py`: one estimator each.

The steps run in the one inner loop (svrpo.algorithm.update.update_policy), their rows drawn by
svrpo.algorithm.step_rows.FreshDraws. Torch only; nothing here imports svrpo.algorithm.estimators
(which registers these estimators).
"""
