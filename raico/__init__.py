"""raico: probabilistic movement planning (AICO, R-AICO, iLQG) on Drake plants, with a cached,
recorded experiment pipeline. Subpackages, floor by floor: thesis -> pipeline -> stages ->
planning -> plants (see docs/layout.md)."""
