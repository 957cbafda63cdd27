"""The learned models: the MLP policy and its action distributions (Gaussian, categoricals,
Bernoullis), the baselines (critics), the observation
normaliser, and flat-parameter helpers.
"""
