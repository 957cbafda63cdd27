"""The algorithm: one outer iteration (iteration.py), the run and its state (run.py,
streams.py), the policy update and its parts (update.py, parts.py, lifecycle.py, estimators.py,
stopping.py) and the surrogate and advantages they read (objectives.py, advantages.py).
The trust-region math is svrpo.algorithm.trust_region, the fresh-sample inner loop svrpo.algorithm.fresh.
"""
