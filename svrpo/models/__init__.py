"""The learned models: the Gaussian MLP policy, the baselines (critics), the observation
normaliser, and flat-parameter helpers.
"""
