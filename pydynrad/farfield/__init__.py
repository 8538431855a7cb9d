"""The far field: light from the patches outside the local set, through a coarse level of clusters."""

from .gather import cluster_form_factors, cluster_form_factors_for

__all__ = ["cluster_form_factors", "cluster_form_factors_for"]
