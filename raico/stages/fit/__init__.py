"""Fit stage: GP hyperparameters by maximum marginal likelihood (library part in ``gp_fit``)."""

from raico.stages.fit.gp_fit import fit_gp, measure_cap_cost, refit_fixed, rmse, subsample_indices

__all__ = ["fit_gp", "measure_cap_cost", "refit_fixed", "rmse", "subsample_indices"]
