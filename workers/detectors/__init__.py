"""Detectors scored on the dataset.

Ideal and sea-marginal observers, matched filter, logistic regression, the trained CNN.
"""
