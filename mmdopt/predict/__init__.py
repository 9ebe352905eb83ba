"""Predictor protocol and predictors: black-box samplers of obstacles' futures."""
