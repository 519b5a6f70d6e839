"""Viewpoint detection models: the paper's per-view Gaussian and hierarchical Bayesian models."""

from scrppl.models.response import (
    ResponseModel,
    check_response_model,
    log_prob,
    predictive_moments,
    sample,
)

__all__ = ["ResponseModel", "check_response_model", "log_prob", "predictive_moments", "sample"]
