"""The execute stage (:mod:`stages.execute.stage`) and its executions by kind: fixed-base
(:mod:`stages.execute.fixed`), floating (:mod:`stages.execute.floating`) and the whole-body stabilizer
(:mod:`stages.execute.wbc`)."""
