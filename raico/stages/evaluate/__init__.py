"""Evaluation: per-run metrics, experiment summaries and the evaluate stage (the thesis's claims are in raico/thesis/claims.py)."""
