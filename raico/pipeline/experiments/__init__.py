"""A user's experiments: experiment files (``raico exp``), their plots, comparisons and solver suites."""
