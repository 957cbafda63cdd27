"""Reading finished runs: learning-curve plots and deterministic evaluation (and video).
"""
