"""Evaluation: per-run metrics, experiment summaries, the thesis's claims and the evaluate stage."""
